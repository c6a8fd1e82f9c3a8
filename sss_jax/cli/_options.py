"""What the sub-commands share: the technique flags built from the technique classes' fields, and the printer that
brings a run's warnings to the user."""

from __future__ import annotations

import sys


class WarningPrinter:
    """Within ``with``: every ``UserWarning`` a run raises (the techniques' ``SamplingWarning`` and
    ``ReferenceWindowWarning``, a frame without SSS pixels, a clamp) printed on stderr once per distinct message, as
    ``<command>: warning: <message>``; other warnings (libraries' deprecations) stay with Python's filters."""

    def __init__(self, command: str):
        self.command = command
        self.messages: list[str] = []
        self._catcher = None

    def __contains__(self, text: str) -> bool:
        return text in self.messages

    def __enter__(self):
        import warnings

        self._catcher = warnings.catch_warnings()
        self._catcher.__enter__()
        warnings.simplefilter("always", UserWarning)  # repeats are dropped below, by message, not by code line
        previous = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if not issubclass(category, UserWarning):
                return previous(message, category, filename, lineno, file, line)
            text = str(message)
            if text not in self.messages:
                self.messages.append(text)
                print(f"{self.command}: warning: {text}", file=sys.stderr, flush=True)

        warnings.showwarning = show
        return self

    def __exit__(self, *exc):
        return self._catcher.__exit__(*exc)
