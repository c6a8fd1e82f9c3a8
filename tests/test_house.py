"""The house rules that hold the package together (issue #20): presets that install, no global state, a public face
that only re-exports, every package directory installed."""

import ast
import pathlib
import re
import subprocess
import sys
import zipfile

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_every_package_directory_is_installed():
    # setuptools' explicit list (needed to map fits/ to sss_jax.fits) must not forget a subpackage
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "sss_jax").rglob("__init__.py")}
    assert found | {"sss_jax.fits"} == listed


def test_library_code_changes_no_global_state():
    # a user's process is not changed by calling a function: no global x64 switch, no matplotlib backend or pyplot
    pattern = re.compile(r"jax_enable_x64|matplotlib\.use|pyplot")
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}" for p in (ROOT / "sss_jax").rglob("*.py")
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert hits == []


def test_public_face_only_reexports():
    tree = ast.parse((ROOT / "sss_jax" / "__init__.py").read_text())
    body = tree.body[1:] if isinstance(tree.body[0], ast.Expr) else tree.body  # the docstring
    assert body and all(isinstance(node, ast.ImportFrom) for node in body)
    for node in body:  # optimistix style: ``from ._x import f as f`` (and the engines' namespace, sss_jax.engines)
        assert node.level == 1 and (node.module.startswith("_") or node.module == "engines")
        assert all(alias.asname == alias.name for alias in node.names)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> pathlib.Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(ROOT)], check=True,
                   capture_output=True)
    (whl,) = out.glob("sss_jax-*.whl")
    return whl


def test_an_ordinary_install_carries_the_presets(wheel, tmp_path):
    # what `pip install .` (not editable) puts in site-packages, run from a directory outside the checkout
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        z.extractall(tmp_path / "site")
    assert {"sss_jax/fits/skin1.json", "sss_jax/fits/montecarlo/skin1.json"} <= names
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import sss_jax as sj; "
            "assert sj.__file__.startswith(sys.argv[1]), sj.__file__; names = sj.list_presets(); "
            "p = sj.load_preset('skin1'); print(len(names), p.name, p.path.startswith(sys.argv[1]))")
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path / "site")], cwd=tmp_path, capture_output=True,
                         text=True, check=True)
    count, name, inside = run.stdout.split()
    assert int(count) >= 17 and name == "skin1" and inside == "True"


def test_the_suite_s_longest_files_are_named_as_they_are_on_disk():
    # conftest.py hands these files to the xdist workers first; a renamed or removed file would silently drop out of
    # that order (and its long tests come last again)
    from conftest import LONGEST_FILES

    here = pathlib.Path(__file__).parent
    missing = [name for name in LONGEST_FILES if not (here / name).is_file()]
    assert not missing, missing
    assert len(set(LONGEST_FILES)) == len(LONGEST_FILES)
