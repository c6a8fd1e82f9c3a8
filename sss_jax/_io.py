"""Image input/output on OpenImageIO (host side, NumPy in and out), with atomic writes.

The pixels of the EXRs a batch reads and writes most (single-part scan-line files of half, float and uint channels,
and outputs whose header attributes are namespaced) go through OpenEXR's own Python binding: OpenImageIO's wheel
undoes the ZIP predictor a byte at a time and copies written pixels a byte at a time, ~2-3x the CPU of OpenEXR's
(a 256x256 five-channel frame: 4.9 -> 1.7 ms read, 8.5 -> 5.3 ms written). Everything else, every header and every
error message still come from OpenImageIO, and ``tests/test_io_cli.py`` checks that both give the same channels,
values and header.

Reading understands three namings of the channels a screen-space pass needs:
- generic: ``R,G,B`` irradiance, ``Z`` (or ``depth.Z``) planar depth, optional ``albedo.R/G/B``, ``N.X/Y/Z``,
  ``thickness``, ``id``;
- Blender multi-layer: ``<ViewLayer>.<pass>.<channel>``: irradiance = ``DiffDir + DiffInd`` (Blender stores diffuse
  light divided by the diffuse colour), albedo = ``DiffCol``, depth = ``Depth.Z`` (background 1e10 -> inf),
  normal = ``Normal`` (world space in Blender: turned into camera space with the camera's orientation from the
  header's ``worldToCamera`` or the sidecar's camera, else not used, with a warning), material id = ``IndexOB`` (or
  ``IndexMA``), every pass from one view layer (the first with the diffuse light passes and depth);
- a user channel map (dict, or a JSON/TOML file) from our buffer names to channel names.

In a multi-part EXR the channels of a later part of several channels carry the part's name (``N.X``, ``albedo.R``);
a part of one channel keeps its bare name (``Z`` of a part ``depth``, ``id`` of a part ``objectid``) unless an
earlier part has it. A data window cropped inside the display window (an auto-cropped render) is read in place in the
display window, zeros around it (no light, no surface); every part of a file must cover the same data window. A data
window reaching past the display window (overscan: Arnold, Karma, RenderMan and Nuke render a margin for the effects
that read neighbours) is read whole, so the margin's pixels feed the pass, and the frame keeps both windows
(``Frame.window``): the batch writes its output with them, so it lies over the input in a compositor.

Depth is planar view depth in scene units; ``depth_kind="distance"`` converts distance-to-camera to planar with the
focal length. Channels stored as integers (an id pass as uint32) keep their values (OpenImageIO's float conversion
would normalise them). Camera intrinsics come from explicit arguments, else the EXR header (``sss_jax:focal_px``,
``sss_jax:mm_per_unit``), else a sidecar ``<stem>.json`` (``camera.focal_px``, ``scene_unit_mm``; without
``focal_px``, the camera's ``lens_mm`` and ``sensor_width_mm`` as Blender gives them, ``focal_from_lens``). A
frame no source gives a unit is read with depth in mm, except a Blender frame (its layout, or Blender's
``BlenderMultiChannel`` header): in metres, Blender's unit, with a warning.

Every write goes to a temporary file in the target directory and is renamed into place: an interrupted run never
leaves a half-written file under the final name.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import math
import os
import pathlib
import socket
import struct
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Mapping
from typing import Any, NamedTuple

import numpy as np

__all__ = ["Frame", "SSSInputError", "NoSSSPixelsWarning", "read_frame", "read_channels", "read_header",
           "exr_is_complete", "exr_chunks_complete", "write_exr", "write_png_preview", "write_json_atomic",
           "write_bytes_atomic", "atomic_path", "check_writable", "display_transform", "load_channel_map"]

_HALF_MAX = 65504.0  # the largest finite half float

BUFFER_NAMES = ("irradiance", "depth", "albedo", "normal", "thickness", "id")


from ._errors import HalfRangeWarning  # noqa: E402
from ._errors import NoSSSPixelsWarning as NoSSSPixelsWarning  # noqa: E402
from ._errors import SSSInputError as SSSInputError  # noqa: E402  (the one definition is in _errors)


def _oiio():
    try:
        import OpenImageIO as oiio
    except ImportError as exc:  # pragma: no cover - a dependency of the package
        raise ImportError("sss_jax needs OpenImageIO for image files: pip install OpenImageIO") from exc
    return oiio


def _openexr():
    """OpenEXR's binding (a dependency), or None where it is missing: then OpenImageIO reads and writes every EXR."""
    try:
        import OpenEXR
    except ImportError:  # pragma: no cover - a dependency of the package
        return None
    return OpenEXR


class Window(NamedTuple):
    """Where a frame's pixels lie on the image plane, as an EXR header says: ``x, y``, the top-left pixel of the
    frame's array (OpenEXR's data window origin), and ``display``, the display window ``(x, y, width, height)``."""

    x: int
    y: int
    display: tuple[int, int, int, int]

    def plain(self, shape: tuple[int, int]) -> bool:
        """Whether an ``(H, W)`` array at this window is what a header without windows means: both windows the
        array's, at (0, 0)."""
        return (self.x, self.y) == (0, 0) and self.display == (0, 0, shape[1], shape[0])

    def principal_point(self) -> tuple[float, float]:
        """The display window's centre in the array's pixel coordinates ``(cx, cy)``: the image centre of the
        frame the camera framed, where the array holds an overscan margin."""
        dx, dy, dw, dh = self.display
        return dx - self.x + dw / 2, dy - self.y + dh / 2


@dataclasses.dataclass(frozen=True)
class Frame:
    """One frame's buffers as NumPy arrays (see ``sss_jax.Buffers`` for the conventions)."""

    irradiance: np.ndarray
    depth: np.ndarray
    albedo: np.ndarray | None = None
    normal: np.ndarray | None = None
    thickness: np.ndarray | None = None
    material_id: np.ndarray | None = None
    focal_px: float | None = None
    mm_per_unit: float | None = None
    path: str | None = None
    layout: str = "generic"
    metadata: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    window: Window | None = None  # the file's data and display windows (None: both the array's, at (0, 0))
    # the camera's principal point in the array's pixels, where it is not the array's centre: the caller's, or the
    # display window's centre of a frame with an overscan margin (``Window.principal_point``)
    principal_point: tuple[float, float] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth.shape

    @property
    def scene_unit_mm(self) -> float:
        """Millimetres per unit of the depth: the frame's ``mm_per_unit``, or 1 where nothing gave one (a generic
        frame's depth read in mm; a Blender frame's reader puts in the metre)."""
        return float(self.mm_per_unit) if self.mm_per_unit is not None else 1.0

    @property
    def sss_pixels(self) -> int:
        """How many pixels a technique scatters: a surface (finite depth) whose id, where there is an id, is >= 1."""
        mask = np.isfinite(self.depth)
        if self.material_id is not None:
            mask &= self.material_id > 0
        return int(np.count_nonzero(mask))

    def camera(self):
        """The frame's ``sss_jax.Camera``: its focal length, its unit (``scene_unit_mm``) and its principal point (the
        display window's centre where the file has an overscan margin). ``SSSInputError`` where nothing gave the
        focal length."""
        from ._scene import Camera

        if self.focal_px is None:
            raise no_focal_length(self.path)
        return Camera(self.focal_px, self.scene_unit_mm, self.principal_point)

    def host_planes(self, *, use_albedo: bool = True) -> Frame:
        """The frame with its planes as the dtypes its JAX buffers take (``use_albedo=False``: without the albedo),
        still NumPy arrays: ``validate_planes`` checks them on the host before ``to_buffers`` puts them on the device
        (on JAX's CPU backend an array just put there is readable only once the computations queued before it are
        done; an accelerator's would be copied back)."""
        import jax

        def host(a, dtype=None):
            a = np.asarray(a)
            return np.asarray(a, dtype or jax.dtypes.canonicalize_dtype(a.dtype))

        opt = lambda a: None if a is None else host(a)
        return dataclasses.replace(self, irradiance=host(self.irradiance), depth=host(self.depth),
                                   albedo=opt(self.albedo) if use_albedo else None, normal=opt(self.normal),
                                   thickness=opt(self.thickness),
                                   material_id=None if self.material_id is None else host(self.material_id, np.int32))

    def to_buffers(self, *, use_albedo: bool = True):
        """The frame as ``sss_jax.Buffers`` (``use_albedo=False`` drops the albedo buffer so materials decide)."""
        import jax

        from ._scene import Buffers

        planes = self.host_planes(use_albedo=use_albedo)

        def put(name: str):
            plane, own = getattr(planes, name), getattr(self, name)
            if plane is None:
                return None
            # a plane that is (or views) this frame's own array goes as a copy: JAX's CPU backend may take a NumPy
            # array without copying it (a 64-byte aligned one), or copy it after the call returns, so the buffers
            # would change with the frame's array, and a JAX array is taken for immutable (a buffer checked once
            # is remembered as checked)
            if own is not None and np.may_share_memory(plane, own):
                plane = plane.copy()
            return jax.device_put(plane)

        return Buffers(**{name: put(name) for name in ("irradiance", "depth", "albedo", "normal", "thickness",
                                                       "material_id")})


# ------------------------------------------------------------------------------------------------------------------
# reading
# ------------------------------------------------------------------------------------------------------------------


def read_channels(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any], tuple[int, int]]:
    """All channels of every subimage as float32 ``(H, W)`` arrays, the header attributes, and ``(H, W)``.

    Channels stored as integers come through OpenImageIO's normalising conversion here (a uint8 PNG's 255 -> 1.0);
    ``read_frame`` reads an id channel's integers themselves (``_read_image``)."""
    channels, _, metadata, shape, _ = _read_image(path)
    return channels, metadata, shape


# OpenImageIO's base types have aliases (UINT is UINT32, UCHAR is UINT8) that its Python enum does not equate
_INTEGER_TYPES = ("UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "UINT64", "INT64", "UINT", "INT", "UCHAR",
                  "CHAR", "USHORT", "SHORT")


def _is_integer(oiio, typedesc) -> bool:
    return any(typedesc.basetype == getattr(oiio, n) for n in _INTEGER_TYPES if hasattr(oiio, n))


def _read_image(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any],
                                                  tuple[int, int], Window]:
    """``(floats, integers, header, (H, W), window)``: every channel as float32, and the channels stored as integers (an
    EXR's ``uint`` id channel, a 16-bit TIFF's) a second time with their stored values, as int64. OpenImageIO's
    float conversion normalises integers by the type's maximum (uint32 1 -> 2.3e-10): right for an 8-bit colour,
    wrong for an object or material id, which must keep its value."""
    oiio = _oiio()
    path = pathlib.Path(path)
    if not path.exists():
        raise SSSInputError(f"{path}: file not found")
    if path.is_dir():
        raise SSSInputError(f"{path}: is a directory, not an image")
    if path.stat().st_size == 0:
        raise SSSInputError(f"{path}: file is empty (0 bytes)")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise SSSInputError(f"{path}: not a readable image ({oiio.geterror() or 'unknown format'})")
    if path.suffix.lower() == ".exr" and inp.format_name() != "openexr":  # OpenImageIO reads by content
        fmt = inp.format_name()
        inp.close()
        raise SSSInputError(f"{path}: named .exr but it is not an OpenEXR file (its content is {fmt})")
    channels: dict[str, np.ndarray] = {}
    integers: dict[str, np.ndarray] = {}
    metadata: dict[str, Any] = {}
    shape, data_window, placed = None, None, None
    try:
        spec = inp.spec()
        fast = _scanline_exr_pixels(path, inp, spec)
        if fast is not None:
            floats, ints = ({name: _in_display_window(a, spec) for name, a in part.items()} for part in fast)
            return (floats, ints, {attr.name: attr.value for attr in spec.extra_attribs}, _frame_shape(spec),
                    _frame_window(spec))
        sub = 0
        while inp.seek_subimage(sub, 0):
            spec = inp.spec()
            if spec.deep:  # samples per pixel, not pixels: read as a flat image they are memory, not light
                raise SSSInputError(f"{path}: a deep image (subimage {sub} holds deep samples); the techniques take "
                                    f"flat buffers: flatten it first (oiiotool {path.name} --flatten -o flat.exr)")
            if shape is None:
                shape, data_window = _frame_shape(spec), (spec.x, spec.y, spec.width, spec.height)
                placed = _frame_window(spec)
                for attr in spec.extra_attribs:
                    metadata[attr.name] = attr.value
                if inp.format_name() != "openexr":  # what a missing channel's message says of the file
                    metadata["sss_jax:file_format"] = inp.format_name()
            elif (spec.x, spec.y, spec.width, spec.height) != data_window:
                # parts of one frame cover the same pixels (a pass at another resolution is not a crop of it)
                x, y, w, h = data_window
                raise SSSInputError(f"{path}: subimage {sub} is {spec.width}x{spec.height} at ({spec.x}, {spec.y}), "
                                    f"the first is {w}x{h} at ({x}, {y})")
            pixels = inp.read_image(sub, 0, 0, spec.nchannels, oiio.FLOAT)
            if pixels is None:
                raise SSSInputError(f"{path}: could not read subimage {sub} (truncated or corrupted: {inp.geterror()})")
            pixels = _in_display_window(np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width,
                                                                                     spec.nchannels), spec)
            part = spec.getattribute("name") if sub > 0 else None
            for c, name in enumerate(spec.channelnames):
                # a later part's channels carry its name ("N.X", "albedo.R"): a part's own names say nothing of
                # what it holds (the Z of a normal part is not depth); a part of one channel keeps its bare name
                # ("Z" of a part "depth", "id" of a part "objectid") unless an earlier part has it
                qualify = part and (spec.nchannels > 1 or name in channels) and not name.startswith(f"{part}.")
                key = f"{part}.{name}" if qualify else name
                channels[key] = pixels[..., c]
                stored = spec.channelformat(c)
                if _is_integer(oiio, stored):
                    raw = inp.read_image(sub, 0, c, c + 1, stored)
                    if raw is None:
                        raise SSSInputError(f"{path}: could not read channel {name!r} of subimage {sub} "
                                            f"({inp.geterror()})")
                    integers[key] = _in_display_window(np.asarray(raw).reshape(spec.height, spec.width), spec
                                                       ).astype(np.int64)
            sub += 1
    finally:
        inp.close()
    if not channels:
        raise SSSInputError(f"{path}: no channels")
    return channels, integers, metadata, shape, placed


def _crop_in_display_window(spec) -> tuple[int, int] | None:
    """``(row, col)`` of the data window in the display window where the data window is a crop strictly inside
    it (an auto-cropped render: Arnold, RenderMan, Nuke write only the pixels that hold something), else None (the
    two windows equal, or a data window reaching past the display window: overscan, read as it is)."""
    row, col = spec.y - spec.full_y, spec.x - spec.full_x
    if (row, col, spec.height, spec.width) == (0, 0, spec.full_height, spec.full_width):
        return None
    if row < 0 or col < 0 or row + spec.height > spec.full_height or col + spec.width > spec.full_width:
        return None
    return row, col


def _frame_window(spec) -> Window:
    """The windows of the frame a file gives (``_frame_shape``): an auto-crop is placed in its display window,
    so the frame's array starts at the display window's corner; otherwise at the data window's."""
    display = (spec.full_x, spec.full_y, spec.full_width, spec.full_height)
    if _crop_in_display_window(spec) is not None:
        return Window(spec.full_x, spec.full_y, display)
    return Window(spec.x, spec.y, display)


def _frame_shape(spec) -> tuple[int, int]:
    """``(H, W)`` of the frame a file gives: its display window where the data window is a crop inside it."""
    if _crop_in_display_window(spec) is None:
        return spec.height, spec.width
    return spec.full_height, spec.full_width


def _in_display_window(a: np.ndarray, spec) -> np.ndarray:
    """The data window's pixels ``a`` (H, W, ...) in place in the display window, zeros around them (no light, no
    surface: a depth of 0 reads as background, an id of 0 as no SSS), where the data window is a crop inside it: the
    techniques see the frame the renderer framed (its borders, its centre for ``depth_kind="distance"``) and the
    output keeps each pixel's place."""
    at = _crop_in_display_window(spec)
    if at is None:
        return a
    out = np.zeros((spec.full_height, spec.full_width) + a.shape[2:], a.dtype)
    out[at[0]:at[0] + spec.height, at[1]:at[1] + spec.width] = a
    return out


def _scanline_exr_pixels(path: pathlib.Path, inp, spec) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]] | None:
    """``_read_image``'s ``(floats, integers)`` of a single-part scan-line EXR, decoded by OpenEXR's binding, the
    channels in OpenImageIO's order, each converted as OpenImageIO converts it (half exactly, uint32 normalised by
    2^32 - 1 in float32, its stored values as int64 beside); ``None`` for every other file (tiled, deep, multi-part,
    sub-sampled channels, a file whose chunks are not all in place, OpenEXR missing): OpenImageIO reads those and
    names what is wrong with a damaged one. The chunk table is checked first so that a truncated file never reaches
    OpenEXR's decoder, which prints its own messages before it fails (a chunk whose data is damaged still does:
    OpenEXR's messages, then OpenImageIO's error)."""
    exr = _openexr()
    if exr is None or inp.format_name() != "openexr" or spec.deep or spec.tile_width or \
            spec.get_int_attribute("oiio:subimages", 1) != 1:
        return None
    try:
        if not _scanline_chunks_intact(path.read_bytes()):
            return None
        with exr.File(str(path), separate_channels=True) as f:
            planes = {name: channel.pixels for name, channel in f.channels().items()}
    except Exception:  # noqa: BLE001 - OpenImageIO reads it again and says what is wrong
        return None
    shape = (spec.height, spec.width)
    if set(planes) != set(spec.channelnames) or any(np.shape(p) != shape for p in planes.values()):
        return None
    floats: dict[str, np.ndarray] = {}
    integers: dict[str, np.ndarray] = {}
    for name in spec.channelnames:
        plane = planes[name]
        if plane.dtype == np.uint32:
            integers[name] = plane.astype(np.int64)
            floats[name] = plane.astype(np.float32) * np.float32(1.0 / 4294967295.0)
        elif plane.dtype in (np.float16, np.float32):
            floats[name] = plane.astype(np.float32, copy=False)
        else:
            return None
    return floats, integers


def read_header(path: str | os.PathLike) -> tuple[dict[str, Any], tuple[int, int]]:
    """The first subimage's header attributes and ``(H, W)``, without reading pixels (cheap)."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise SSSInputError(f"{path}: not a readable image ({oiio.geterror() or 'unknown format'})")
    try:
        spec = inp.spec()
        return {a.name: a.value for a in spec.extra_attribs}, _frame_shape(spec)
    finally:
        inp.close()


def exr_is_complete(path: str | os.PathLike) -> bool:
    """Whether every pixel of the file decodes (a truncated or damaged file does not)."""
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear it
        return False
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None:
            inp.geterror()
        return pixels is not None
    finally:
        inp.close()


# the first four bytes of every OpenEXR file
EXR_MAGIC = b"\x76\x2f\x31\x01"

# scan lines per chunk of each OpenEXR compression (the OpenEXR file layout's table)
_EXR_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}


def _exr_chunk_table(data: bytes) -> tuple[int, int, int, int] | None:
    """``(first y, lines per chunk, chunks)`` and where the offset table starts, from a single-part scanline EXR's
    header (``None`` for any other layout: tiled, multi-part, deep, or a header this reader does not follow)."""
    if len(data) < 8 or data[:4] != EXR_MAGIC:
        return None
    flags = struct.unpack_from("<I", data, 4)[0]
    if flags & 0x1a00:  # tiled (0x200), deep (0x800), multi-part (0x1000)
        return None
    pos, compression, window = 8, None, None
    while pos < len(data) and data[pos] != 0:
        name_end = data.index(b"\0", pos)
        type_end = data.index(b"\0", name_end + 1)
        (size,) = struct.unpack_from("<i", data, type_end + 1)
        value = type_end + 5
        name = data[pos:name_end]
        if name == b"compression":
            compression = data[value]
        elif name == b"dataWindow":
            window = struct.unpack_from("<iiii", data, value)
        pos = value + size
    if compression not in _EXR_LINES_PER_CHUNK or window is None or pos >= len(data):
        return None
    lines = _EXR_LINES_PER_CHUNK[compression]
    return window[1], lines, -(-(window[3] - window[1] + 1) // lines), pos + 1


def exr_chunks_complete(path: str | os.PathLike) -> bool:
    """Whether a single-part scanline EXR holds every chunk its offset table lists, each where the table says, in
    order, the last ending at the end of the file: what a write that lost data (a full disk, an I/O error, a
    truncation) cannot leave, checked from the file's bytes without decoding the pixels (~50x cheaper than
    ``exr_is_complete`` on a 256x256 frame). Other layouts (tiled, multi-part) are decoded (``exr_is_complete``)."""
    try:
        data = pathlib.Path(path).read_bytes()
    except OSError:
        return False
    intact = _scanline_chunks_intact(data)
    return exr_is_complete(path) if intact is None else intact


def _scanline_chunks_intact(data: bytes) -> bool | None:
    """``exr_chunks_complete`` on a file's bytes: ``None`` for a layout the chunk table does not describe alone
    (tiled, deep, multi-part)."""
    try:
        table = _exr_chunk_table(data)
    except (ValueError, struct.error):  # a header cut short
        return False
    if table is None:
        return None
    y0, lines, chunks, start = table
    if start + 8 * chunks > len(data):
        return False
    offsets = struct.unpack_from(f"<{chunks}Q", data, start)
    end = start + 8 * chunks
    for i, offset in enumerate(offsets):
        if offset != end or offset + 8 > len(data):  # chunks written in order, each right after the one before
            return False
        y, size = struct.unpack_from("<ii", data, offset)
        if y != y0 + i * lines or size <= 0:
            return False
        end = offset + 8 + size
    return end == len(data)


DEPTH_KINDS = ("planar", "distance")


def check_depth_kind(depth_kind: str) -> None:
    """``depth_kind`` is one of ``DEPTH_KINDS`` (the depth along the view axis, or the distance to the camera)."""
    if depth_kind not in DEPTH_KINDS:
        raise SSSInputError(f"depth_kind={depth_kind!r} is not one of {DEPTH_KINDS}")


def load_channel_map(source: str | os.PathLike | Mapping[str, Any]) -> dict[str, Any]:
    """A channel map from a dict or a ``.json`` / ``.toml`` file: buffer name -> channel name(s)."""
    if isinstance(source, Mapping):
        data = dict(source)
        origin = "channel map"
    elif not isinstance(source, (str, os.PathLike)):
        raise SSSInputError(f"channel map: a dict of buffer name -> channel name(s), or a .json/.toml file's path; "
                            f"got a {type(source).__name__}")
    else:
        p = pathlib.Path(source)
        origin = str(p)
        try:
            text = p.read_text()
        except OSError as exc:
            raise SSSInputError(f"{p}: cannot read channel map ({exc.strerror})") from None
        except UnicodeDecodeError as exc:
            raise SSSInputError(f"{p}: a channel map is UTF-8 text (JSON or TOML); byte {exc.start} is not "
                                f"UTF-8 ({exc.reason})") from None
        try:
            if p.suffix.lower() == ".toml":
                import tomllib

                data = tomllib.loads(text)
            else:
                data = json.loads(text)
        except Exception as exc:
            raise SSSInputError(f"{p}: invalid channel map ({exc})") from None
    if not isinstance(data, dict):
        raise SSSInputError(f"{origin}: a channel map must be a table of buffer name -> channel name(s)")
    for key, value in data.items():
        if key == "layer":  # a Blender view layer to read every pass from (``_blender_layers``)
            if not isinstance(value, str):
                raise SSSInputError(f"{origin}: 'layer' needs a view layer's name, got {value!r}")
            continue
        if key not in BUFFER_NAMES:
            raise SSSInputError(f"{origin}: unknown buffer {key!r}; known buffers: {', '.join(BUFFER_NAMES)} "
                                "(and 'layer', a Blender view layer)")
        want = 3 if key in ("irradiance", "albedo", "normal") else 1
        names = [value] if isinstance(value, str) else value
        if not isinstance(names, list) or len(names) != want or not all(isinstance(n, str) for n in names):
            raise SSSInputError(f"{origin}: {key!r} needs {want} channel name(s), got {value!r}")
    return data


def _blender_layers(names: list[str], path, layer: str | None = None, *, choose: str | None = None) -> dict[str, str]:
    """``{pass.channel: full name}`` of one view layer of Blender's ``<layer>.<pass>.<channel>`` channels, every pass
    taken from that layer (a frame is never put together from two layers' passes: each layer has its own Depth):
    ``layer`` where named, else the layer with the diffuse light passes and Depth, else with Combined and Depth, else
    with Depth, else with Combined, else the first. Two layers that both fit the first of these that any fits are
    ambiguous (one may be lit and the other black): ``SSSInputError`` naming them, and how to choose (``choose``; by
    default a channel map's ``layer``)."""
    layers: dict[str, dict[str, str]] = {}
    for n in names:
        parts = n.split(".")
        if len(parts) >= 3:
            layers.setdefault(".".join(parts[:-2]), {}).setdefault(".".join(parts[-2:]), n)
    if layer is not None:
        if layer not in layers:
            raise SSSInputError(f"{path}: the channel map's layer {layer!r} is not in the file; its view layers: "
                                f"{', '.join(map(repr, layers)) or 'none'}")
        return layers[layer]
    has = lambda layer, name: all(f"{name}.{c}" in layer for c in "RGB")
    for wanted in (lambda layer: has(layer, "DiffDir") and "Depth.Z" in layer,
                   lambda layer: has(layer, "Combined") and "Depth.Z" in layer,
                   lambda layer: "Depth.Z" in layer,
                   lambda layer: has(layer, "Combined")):  # an offline render's layers: the image alone
        fits = [name for name, passes in layers.items() if wanted(passes)]
        if len(fits) > 1:
            how = (f"name the one to read in a channel map: {json.dumps({'layer': fits[0]})} (--channel-map)"
                   if choose is None else choose.format(layer=fits[0]))
            raise SSSInputError(f"{path}: {len(fits)} view layers hold the passes ({', '.join(map(repr, fits))}); "
                                + how)
        if fits:
            return layers[fits[0]]
    return next(iter(layers.values()), {})


# a depth channel outside Blender's layers: generic, a multi-part file's part ``depth``, Nuke's ``depth.Z``
_DEPTH_NAMES = ("Z", "depth.Z", "Depth.Z", "depth", "Z.Z")


def _first(channels: dict[str, np.ndarray], *candidates: str) -> str | None:
    for c in candidates:
        if c in channels:
            return c
    return None


def _resolve(channels: dict[str, np.ndarray], channel_map: Mapping[str, Any] | None, path) -> tuple[dict, str]:
    """Which channels make which buffer, and the name of the layout recognised."""
    names = list(channels)
    found = ", ".join(names[:24]) + (" ..." if len(names) > 24 else "")
    plan: dict[str, list[str] | tuple] = {}
    layer = (channel_map or {}).get("layer")
    channel_map = {k: v for k, v in (channel_map or {}).items() if k != "layer"}  # buffers named, if any
    if layer is not None and channel_map:
        raise SSSInputError(f"{path}: a channel map names either the buffers' channels or a view layer to read them "
                            f"from, not both (it names the layer {layer!r} and {', '.join(channel_map)})")
    if channel_map:
        for key, value in channel_map.items():
            cols = [value] if isinstance(value, str) else list(value)
            missing = [c for c in cols if c not in channels]
            if missing:
                raise SSSInputError(f"{path}: channel map names missing channel(s) {missing}; channels found: {found}")
            plan[key] = cols
        layout = "channel-map"
    else:
        blender = _blender_layers(names, path, layer)
        if "DiffDir.R" in blender or "Depth.Z" in blender or layer is not None:
            layout = "blender"
            rgb = lambda p: [blender.get(f"{p}.{c}") for c in "RGB"]
            if all(rgb("DiffDir")) and all(rgb("DiffInd")):
                plan["irradiance"] = ("sum", rgb("DiffDir"), rgb("DiffInd"))
            elif all(rgb("DiffDir")):
                plan["irradiance"] = rgb("DiffDir")
            elif all(rgb("Combined")):
                plan["irradiance"] = rgb("Combined")
            # the layer's Depth, else a depth channel of its own (``Z`` beside the layer, or a multi-part file's part
            # ``depth``)
            z = blender.get("Depth.Z") or _first(channels, *_DEPTH_NAMES)
            if z:
                plan["depth"] = [z]
            if all(rgb("DiffCol")):
                plan["albedo"] = rgb("DiffCol")
            normal = [blender.get(f"Normal.{c}") for c in "XYZ"]
            if all(normal):
                plan["normal"] = normal
            idx = blender.get("IndexOB.X") or blender.get("IndexMA.X")
            if idx:
                plan["id"] = [idx]
        else:
            layout = "generic"
            if all(c in channels for c in "RGB"):
                plan["irradiance"] = ["R", "G", "B"]
            z = _first(channels, *_DEPTH_NAMES)
            if z:
                plan["depth"] = [z]
            if all(f"albedo.{c}" in channels for c in "RGB"):
                plan["albedo"] = [f"albedo.{c}" for c in "RGB"]
            if all(f"N.{c}" in channels for c in "XYZ"):
                plan["normal"] = [f"N.{c}" for c in "XYZ"]
            t = _first(channels, "thickness", "thickness.Y", "T")
            if t:
                plan["thickness"] = [t]
            i = _first(channels, "id", "id.Y", "matid")
            if i:
                plan["id"] = [i]
    for required in ("irradiance", "depth"):
        if required not in plan and layout == "channel-map":  # a map says where every buffer is, or it is not read
            raise SSSInputError(f"{path}: the channel map names no {required} channel(s); a map names the "
                                f"irradiance and the depth, and any of albedo, normal, thickness, id; channels "
                                f"found: {found}")
        if required not in plan:
            what = "R, G, B" if required == "irradiance" else "Z"
            raise SSSInputError(
                f"{path}: missing {required} channel(s) (expected {what}, Blender passes, or a channel map); "
                f"channels found: {found}"
            )
    return plan, layout


def _flat_names(spec) -> list[str]:
    """The channel names of a plan's entry (a list, or ``("sum", a, b)`` of two lists)."""
    if isinstance(spec, tuple) and spec[0] == "sum":
        return _flat_names(spec[1]) + _flat_names(spec[2])
    return list(spec)


def _names(spec) -> str:
    return ", ".join(repr(n) for n in _flat_names(spec))


def _pass_read(path: pathlib.Path, what: str, spec, values: np.ndarray, scattered: np.ndarray, *,
               posinf: bool = False) -> np.ndarray:
    """A pass (``albedo``, ``normal``, ``thickness``) as float32, its non-finite values where nothing reads them
    (``~scattered``: background, id 0) read as 0, and ``SSSInputError`` naming the file, the channels, how many
    values and the first pixel where a scattered pixel's value is not finite (``posinf``: inf is a value, as an
    infinite thickness): a renderer's NaN there would silently become a black, a bright or a flat pixel."""
    from ._scene import _first_pixel

    values = values.astype(np.float32)
    mask = scattered if values.ndim == scattered.ndim else scattered[..., None]
    valid = np.isfinite(values) | (posinf & (values == np.inf))
    bad = ~valid & mask
    if bad.any():
        pixel = bad if bad.ndim == scattered.ndim else bad.any(-1)
        raise SSSInputError(f"{path}: {what} channel(s) {_names(spec)} have {int(bad.sum())} non-finite value(s) on "
                            f"pixels that scatter (the first at {_first_pixel(pixel)}); the {what} pass must be finite "
                            "there")
    return values if valid.all() else np.where(valid, values, np.float32(0.0))


def _stack(channels: dict[str, np.ndarray], spec) -> np.ndarray:
    if isinstance(spec, tuple) and spec[0] == "sum":
        return _stack(channels, spec[1]) + _stack(channels, spec[2])
    arrays = [channels[c] for c in spec]
    return arrays[0] if len(arrays) == 1 else np.stack(arrays, axis=-1)


def _header_number(path: pathlib.Path, name: str, given, *sources: tuple[Any, str]) -> float | None:
    """``given`` (the caller's) or the first source that is set (None or an empty text is unset), as a positive
    finite float; ``SSSInputError`` naming where a value that is not one came from. (A 0 counted as unset before: a
    sidecar's ``scene_unit_mm: 0`` was passed over for 1 mm a unit without a word, the scene read 10-1000x off.)"""
    value, where = given, f"the {name} argument"
    if value is None:
        value, where = next(((v, w) for v, w in sources if v is not None and not (isinstance(v, str) and not v)),
                            (None, ""))
    if value is None:
        return None
    try:
        if isinstance(value, (bool, np.bool_)):  # float(True) is 1.0: a flag, not a length
            raise TypeError(name)
        number = float(value)
    except (TypeError, ValueError):
        raise SSSInputError(f"{path}: {name} from {where} is {value!r}, not a number") from None
    if not 0 < number < math.inf:
        raise SSSInputError(f"{path}: {name} from {where} is {value!r}: it must be a positive number")
    return number


BLENDER_MM_PER_UNIT = 1000.0  # Blender's scene unit at the default unit scale: the metre
# Raised whenever the same file and arguments read as other buffers or another camera (2: a Blender frame without a
# unit in metres, not mm; the focal length from a sidecar's lens): a batch's resume record holds it, so outputs made
# under an older reading are computed again instead of kept
READER_REVISION = 2


def focal_from_lens(camera: Mapping[str, Any], display: tuple[int, int], *, where: str, resolution=None,
                    pixel_aspect=None) -> float | None:
    """The focal length in pixels from a camera's lens and sensor in millimetres, as Blender describes a camera
    (``lens_mm``, ``sensor_width_mm``, ``sensor_height_mm``, ``sensor_fit``: ``AUTO``, the default, fits the sensor
    width to the larger of the image's width and height, ``HORIZONTAL`` to its width, ``VERTICAL`` the sensor height
    to its height), for an image of ``display = (width, height)`` pixels; None where the camera gives no lens.

    The sensor spans the rendered image, so the file must be all of it: ``resolution`` (the render's ``(width,
    height)`` where the description states it) other than ``display`` (a render cropped to a region, or scaled) and
    non-square pixels (``pixel_aspect``, the header's ``PixelAspectRatio``) are errors that ask for ``focal_px``."""
    lens = camera.get("lens_mm")
    if lens is None:
        return None
    if resolution is not None:
        try:
            res = tuple(int(v) for v in resolution)
        except (TypeError, ValueError):
            res = ()
        if len(res) != 2:
            raise SSSInputError(f"{where}: resolution must be [width, height], got {resolution!r}")
        if res != tuple(display):
            raise SSSInputError(f"{where}: the render's resolution {res[0]}x{res[1]} is not the file's "
                                f"{display[0]}x{display[1]} (cropped or scaled?): its lens gives no focal length for "
                                "this file; pass focal_px (--focal-px)")
    if pixel_aspect is not None and not math.isclose(float(pixel_aspect), 1.0, rel_tol=1e-6):
        raise SSSInputError(f"{where}: pixels are not square (PixelAspectRatio {float(pixel_aspect):g}): the lens "
                            "gives no single focal length; pass focal_px (--focal-px)")
    fit = str(camera.get("sensor_fit", "AUTO")).upper()
    if fit not in ("AUTO", "HORIZONTAL", "VERTICAL"):
        raise SSSInputError(f"{where}: sensor_fit must be AUTO, HORIZONTAL or VERTICAL, got {camera['sensor_fit']!r}")
    width, height = display
    key, pixels = {"AUTO": ("sensor_width_mm", max(width, height)), "HORIZONTAL": ("sensor_width_mm", width),
                   "VERTICAL": ("sensor_height_mm", height)}[fit]
    if camera.get(key) is None:
        raise SSSInputError(f"{where}: lens_mm {lens!r} needs {key} (sensor_fit {fit}) to give the focal length")
    values = []
    for name, v in (("lens_mm", lens), (key, camera[key])):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float)) or not 0 < v < math.inf:
            raise SSSInputError(f"{where}: {name} must be a positive number of millimetres, got {v!r}")
        values.append(float(v))
    return values[0] / values[1] * pixels


def _focal_sources(path) -> str:
    side = pathlib.Path(path).with_suffix(".json").name
    return (f"pass focal_px (--focal-px), put sss_jax:focal_px in the EXR header, or camera.focal_px (or "
            f"camera.lens_mm and sensor_width_mm) in the sidecar {side}")


def no_focal_length(path) -> SSSInputError:
    """The error for a frame whose focal length nothing gave: where it can come from."""
    return SSSInputError(f"{path}: no focal length: {_focal_sources(path)}")


def _sidecar(path: pathlib.Path) -> dict[str, Any]:
    side = path.with_suffix(".json")
    if not side.exists():
        return {}
    try:
        data = json.loads(side.read_text())
    except Exception as exc:
        raise SSSInputError(f"{side}: invalid scene description JSON ({exc})") from None
    if not isinstance(data, dict):  # passed over before, and the frame then told to put its camera in this file
        raise SSSInputError(f"{side}: a scene description is a JSON object ({{\"camera\": {{...}}, "
                            f"\"scene_unit_mm\": ...}}), not a {type(data).__name__}")
    return data


def world_to_camera_rotation(metadata: Mapping[str, Any], side: Mapping[str, Any],
                             path: str | os.PathLike = "") -> tuple[np.ndarray, str] | None:
    """The rotation ``R (3, 3)`` taking world-space directions to sss_jax's camera space (x right, y down, z forward:
    ``n_cam = R @ n_world``) and where it came from, or None when neither source has the camera's orientation.

    Sources, in order: the EXR header's standard ``worldToCamera`` (OpenEXR: row vectors, ``p' = p M``; its camera
    space is x right, y up, z the viewing direction), then the sidecar's ``camera.matrix_world`` (Blender: the
    camera's 4x4 camera-to-world, columns; the camera looks down its -Z with +Y up) or ``camera.location`` and
    ``camera.look_at`` (with ``camera.up``, default Blender's world +Z). A value that is not the numbers it must be
    (an exporter's ``{"x": ..}`` object, a 3x3 matrix, a camera looking at itself) is an ``SSSInputError`` naming the
    file (``path``, the frame) and the field."""
    sidecar = pathlib.Path(path).with_suffix(".json") if path else "the sidecar"

    def numbers(value, size: int, where: str) -> np.ndarray:
        try:
            a = np.asarray(value, np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or a.size != size or not np.all(np.isfinite(a)):
            raise SSSInputError(f"{where} must be {size} finite numbers, got {value!r}")
        return a.reshape(-1)

    def unit(v: np.ndarray, where: str) -> np.ndarray:
        norm = float(np.linalg.norm(v))
        if not norm > 0:
            raise SSSInputError(f"{where} has no direction (a zero vector): no camera orientation")
        return v / norm

    flip_y = np.diag([1.0, -1.0, 1.0])
    m = metadata.get("worldToCamera")
    if m is not None:
        m = numbers(m, 16, f"{path}: the header's worldToCamera").reshape(4, 4)
        return flip_y @ m[:3, :3].T, "the EXR header's worldToCamera"
    cam = side.get("camera") if isinstance(side.get("camera"), dict) else {}
    if cam.get("matrix_world") is not None:
        c2w = numbers(cam["matrix_world"], 16, f"{sidecar}: camera.matrix_world").reshape(4, 4)[:3, :3]
        # columns: the camera's x (right), y (up), z (backwards) in world space
        right, up, back = (unit(c2w[:, k], f"{sidecar}: camera.matrix_world's column {k}") for k in range(3))
        return np.stack([right, -up, -back]), "the sidecar's camera.matrix_world"
    if cam.get("location") is not None and cam.get("look_at") is not None:
        location = numbers(cam["location"], 3, f"{sidecar}: camera.location")
        forward = unit(numbers(cam["look_at"], 3, f"{sidecar}: camera.look_at") - location,
                       f"{sidecar}: camera.look_at - camera.location")
        world_up = numbers(cam.get("up", (0.0, 0.0, 1.0)), 3, f"{sidecar}: camera.up")
        right = np.cross(forward, world_up)
        if not np.linalg.norm(right) > 1e-9:
            return None
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        return np.stack([right, -up, forward]), "the sidecar's camera.location and look_at"
    return None


def distance_to_planar(distance: np.ndarray, focal_px: float, principal_point: tuple[float, float] | None = None):
    """Planar depth from distance to the camera: ``z = dist / sqrt(1 + ((x-cx)^2 + (y-cy)^2) / f^2)`` at pixel centres
    ``(x + 0.5, y + 0.5)``; the principal point defaults to the image centre."""
    h, w = distance.shape
    cx, cy = principal_point if principal_point is not None else (w / 2, h / 2)
    xs = (np.arange(w) + 0.5 - cx) / focal_px
    ys = (np.arange(h) + 0.5 - cy) / focal_px
    return (distance / np.sqrt(1 + xs[None, :] ** 2 + ys[:, None] ** 2)).astype(np.float32)


def read_frame(
    path: str | os.PathLike,
    *,
    channel_map: str | os.PathLike | Mapping[str, Any] | None = None,
    depth_kind: str = "planar",
    focal_px: float | None = None,
    mm_per_unit: float | None = None,
    principal_point: tuple[float, float] | None = None,
    depth_path: str | os.PathLike | None = None,
) -> Frame:
    """Read one frame's buffers from an EXR (see the module docstring for the namings understood).

    ``depth_kind``: ``"planar"`` (view depth along the camera axis) or ``"distance"`` (to the camera centre; converted
    with ``focal_px``). ``depth_path``: depth from a separate single-channel file of the same resolution.
    """
    path = pathlib.Path(path)
    check_depth_kind(depth_kind)
    return _frame_from_decoded(path, _read_image(path), channel_map=channel_map, depth_kind=depth_kind,
                               focal_px=focal_px, mm_per_unit=mm_per_unit, principal_point=principal_point,
                               depth_path=depth_path)


def _frame_from_decoded(path: pathlib.Path, decoded, *, channel_map, depth_kind: str, focal_px: float | None,
                        mm_per_unit: float | None, principal_point=None, depth_path=None,
                        warn: Callable[[str, type[Warning]], None] | None = None) -> Frame:
    """``read_frame`` after the decode: ``decoded`` is what ``_read_image(path)`` returned. ``warn(message,
    category)`` takes the warnings instead of ``warnings.warn`` (a batch reads the next frame in a thread while the
    current one computes, and says them in the main thread: the warnings module's state is not thread-safe)."""
    if warn is None:
        warn = lambda message, category: warnings.warn(message, category, stacklevel=4)
    check_depth_kind(depth_kind)
    channels, integers, metadata, shape, window = decoded
    if principal_point is None and window is not None and not window.plain(shape):
        principal_point = window.principal_point()  # an overscan margin: the framed image's centre
    aspect = _header_number(path, "PixelAspectRatio", None, (metadata.get("PixelAspectRatio"), "the header"))
    if aspect is not None and not math.isclose(aspect, 1.0, rel_tol=1e-4):
        w = shape[1]
        raise SSSInputError(f"{path}: pixels are not square (PixelAspectRatio {aspect:g}): the techniques measure a "
                            f"material's reach in square pixels, so its kernel would be {aspect:g}x off along x; "
                            f"resample the frame to square pixels first (e.g. oiiotool {path.name} --resize "
                            f"{round(w * aspect)}x{shape[0]} -o square.exr)")
    cmap = load_channel_map(channel_map) if channel_map is not None else None
    if depth_path is not None:
        d_channels, _, d_shape = read_channels(depth_path)
        if d_shape != shape:
            raise SSSInputError(
                f"{depth_path}: depth is {d_shape[1]}x{d_shape[0]} but {path} is {shape[1]}x{shape[0]}"
            )
        key = _first(d_channels, "Z", "depth.Z", "Depth.Z", "Y", "R") or next(iter(d_channels))
        channels = dict(channels, **{"Z": d_channels[key]})
    try:
        plan, layout = _resolve(channels, cmap, path)
    except SSSInputError as exc:
        fmt = metadata.get("sss_jax:file_format")
        if fmt is None:
            raise
        raise SSSInputError(f"{exc} (a {fmt.upper()} file, not OpenEXR: a frame is linear light and depth, as a "
                            "renderer writes them in an EXR)") from None
    if layout == "blender" and any(".Combined." in name for name in plan["irradiance"]):
        warn(f"{path}: no diffuse light passes (DiffDir, DiffInd): the irradiance is the Combined pass, which is "
             "shaded already (the surface colour, specular and emission in it), so the albedo counts twice and the "
             "highlights scatter; render the Diffuse Direct, Indirect and Color passes", UserWarning)
    elif layout == "blender" and not isinstance(plan["irradiance"], tuple) and \
            any(".DiffDir." in name or name.startswith("DiffDir.") for name in plan["irradiance"]):
        warn(f"{path}: no Diffuse Indirect pass (DiffInd): the irradiance is the direct diffuse light alone, the "
             "light bounced between surfaces left out; render the Diffuse Indirect pass too", UserWarning)
    if "sss_jax:file_format" not in metadata:  # an EXR's integer channel holds ids or counts, never light or lengths
        for key, names in plan.items():
            stored = [n for n in _flat_names(names) if n in integers]
            if key != "id" and stored:
                raise SSSInputError(f"{path}: {key} channel(s) {_names(stored)} are stored as unsigned integers (an "
                                    f"id or count pass, not {key}); map {key} to half or float channels "
                                    "(channel_map, --channel-map)")
    buffers = {k: _stack(channels, v) for k, v in plan.items()}

    side = _sidecar(path)
    camera_side = side.get("camera") if isinstance(side.get("camera"), dict) else {}  # an exporter may name it
    sidecar = path.with_suffix(".json").name
    focal_px = _header_number(path, "focal_px", focal_px, (metadata.get("sss_jax:focal_px"), "sss_jax:focal_px"),
                              (camera_side.get("focal_px"), f"camera.focal_px of {sidecar}"))
    if focal_px is None:
        display = window.display[2:] if window is not None else (shape[1], shape[0])
        focal_px = focal_from_lens(camera_side, display, where=f"{path}: camera of {sidecar}",
                                   resolution=side.get("resolution"), pixel_aspect=metadata.get("PixelAspectRatio"))
    mm_per_unit = _header_number(path, "mm_per_unit", mm_per_unit,
                                 (metadata.get("sss_jax:mm_per_unit"), "sss_jax:mm_per_unit"),
                                 (side.get("scene_unit_mm"), f"scene_unit_mm of {sidecar}"))
    if mm_per_unit is None and (layout == "blender" or "BlenderMultiChannel" in metadata):
        # Blender's depth is in its scene unit, the metre at the default unit scale; read as 1 mm a unit (what a
        # generic frame without a unit gets) every material would be 1000 times wider than the user meant
        mm_per_unit = BLENDER_MM_PER_UNIT
        warn(f"{path}: no scene unit (sss_jax:mm_per_unit in the header, scene_unit_mm in a sidecar {sidecar}, or "
             f"mm_per_unit / --mm-per-unit): Blender's depth read in metres ({BLENDER_MM_PER_UNIT:g} mm a unit); "
             "give the unit if the scene's unit scale is not 1", UserWarning)

    depth = buffers["depth"].astype(np.float32)
    from ._scene import _first_pixel, surface_mask  # (here: _io itself imports no JAX)

    depth = np.where(surface_mask(depth), depth, np.inf).astype(np.float32)
    if depth_kind == "distance":
        if focal_px is None:
            raise SSSInputError(f"{path}: depth_kind='distance' needs the focal length to convert the depth to "
                                f"planar: {_focal_sources(path)}")
        depth = np.where(np.isfinite(depth), distance_to_planar(np.where(np.isfinite(depth), depth, 1.0), focal_px,
                                                                 principal_point), np.inf).astype(np.float32)
    irradiance = np.asarray(buffers["irradiance"], np.float32)
    if not np.all(np.isfinite(irradiance)):
        raise SSSInputError(f"{path}: irradiance has {int(np.sum(~np.isfinite(irradiance)))} non-finite values")
    # negatives read as 0: a lossy codec's ringing around 0 (DWAA: -6e-6 beside 2.8) silently, more than a
    # thousandth of the frame's largest value said (a difference of two renders, or another pass taken for light)
    low, high = float(irradiance.min(initial=0.0)), float(irradiance.max(initial=0.0))
    if low < -1e-3 * high or (low < 0 and high <= 0):
        warn(f"{path}: irradiance has {int(np.sum(irradiance < 0))} negative value(s) (down to {low:.3g}, the "
             f"largest {high:.3g}), read as 0: a light pass holds no negative light", UserWarning)
    irradiance = np.maximum(irradiance, 0.0)
    ids = buffers.get("id")
    if ids is not None:
        (id_channel,) = plan["id"]
        if id_channel in integers:  # stored as integers: their values, not OpenImageIO's normalised floats
            ids = integers[id_channel]
        elif not np.all(np.isfinite(ids)):
            raise SSSInputError(f"{path}: id channel has non-finite values")
        else:
            whole = np.rint(ids)
            # ids stored as floats hold whole numbers (Blender's IndexOB, half or float); a fraction is a filtered
            # (anti-aliased) or scaled pass, or another channel: rounding it picked materials silently (0.5 -> 0)
            off = np.abs(ids - whole) > 1e-3
            if off.any():
                raise SSSInputError(f"{path}: id channel {id_channel!r} has {int(off.sum())} value(s) that are not "
                                    f"whole numbers (the first {float(ids[off][0]):.4g}, at {_first_pixel(off)}); ids "
                                    "select materials 1, 2, ...: an unfiltered id pass (Blender's IndexOB), or a "
                                    "channel map to one")
            ids = whole
        if np.any(ids < 0):
            raise SSSInputError(f"{path}: id channel has negative ids (min {int(ids.min())})")
        if np.any(ids > np.iinfo(np.int32).max):
            raise SSSInputError(f"{path}: id channel {id_channel!r} has ids up to {int(ids.max())}; ids select "
                                f"materials 1, 2, ... and must be below 2^31 (a hashed id such as Cryptomatte's "
                                "needs a channel map to a small-integer id pass)")
        ids = ids.astype(np.int32)
    scattered = np.isfinite(depth) if ids is None else np.isfinite(depth) & (ids > 0)
    albedo = buffers.get("albedo")
    if albedo is not None:
        albedo = _pass_read(path, "albedo", plan["albedo"], albedo, scattered)
        outside = scattered[..., None] & ((albedo < -1e-3) | (albedo > 1 + 1e-3))  # beyond a lossy codec's ringing
        if outside.any():
            low, high = float(albedo[scattered].min()), float(albedo[scattered].max())
            warn(f"{path}: albedo channels {_names(plan['albedo'])} have {int(outside.sum())} value(s) outside "
                 f"[0, 1] on scattered pixels ({low:.3g} to {high:.3g}; the first at {_first_pixel(outside.any(-1))}), "
                 "read clipped to [0, 1]: a diffuse colour pass reflects at most the light it receives", UserWarning)
        albedo = np.clip(albedo, 0.0, 1.0)
    normal = buffers.get("normal")
    if normal is not None:
        normal = _pass_read(path, "normal", plan["normal"], normal, scattered)
        if layout == "blender":  # Blender's Normal pass is in world space; the techniques take camera space
            rotation = world_to_camera_rotation(metadata, side, path)
            if rotation is None:
                warn(f"{path}: the Normal pass is in world space (Blender) and neither the header "
                     f"(worldToCamera) nor a sidecar {path.with_suffix('.json').name} (camera.location and "
                     "look_at, or matrix_world) gives the camera's orientation: the pass is not used "
                     "(normals come from depth)", UserWarning)
                normal = None
            else:
                normal = (normal.astype(np.float64) @ rotation[0].T).astype(np.float32)
    thickness = buffers.get("thickness")
    if thickness is not None:  # inf: infinitely thick, as the models read it; negative: 0
        thickness = np.maximum(_pass_read(path, "thickness", plan["thickness"], thickness, scattered, posinf=True), 0.0)
    frame = Frame(irradiance=irradiance, depth=depth, albedo=albedo, normal=normal, thickness=thickness,
                  material_id=ids, focal_px=focal_px, mm_per_unit=mm_per_unit, path=str(path), layout=layout,
                  metadata=metadata, window=window, principal_point=principal_point)
    surface = np.isfinite(depth)
    lost = None if ids is None else (ids > 0) & ~surface  # a material without a surface to scatter on
    if frame.sss_pixels == 0:
        if not surface.any():
            why = (f"depth channel {plan['depth'][0]!r} has no surface (every value is NaN, 0, negative, inf or "
                   "background)")
        elif lost is not None and lost.any():
            why = (f"no pixel whose id ({plan['id'][0]!r}) is above 0 has a surface in depth channel "
                   f"{plan['depth'][0]!r} (its depth there is NaN, 0, negative, inf or background)")
        else:
            why = (f"id channel {plan['id'][0]!r} is 0 on every surface pixel (0 = no SSS); ids stored as floats "
                   "must hold the integer values 1, 2, ...")
        warn(f"{path}: no pixel to scatter: {why}; the output is the input", NoSSSPixelsWarning)
    elif lost is not None and lost.any():  # none in Blender's renders (ids and depth from the same first hit)
        warn(f"{path}: {int(lost.sum())} pixel(s) with an id above 0 have no surface in depth channel "
             f"{plan['depth'][0]!r} (NaN, 0, negative, inf or background depth; the first at {_first_pixel(lost)}): "
             "they keep their input, unscattered and without the albedo", UserWarning)
    return frame


# ------------------------------------------------------------------------------------------------------------------
# writing (atomic)
# ------------------------------------------------------------------------------------------------------------------


def check_writable(path: str | os.PathLike, *, create_dirs: bool = True) -> pathlib.Path:
    """Check, before any work, that a file can be written at ``path``: its folder exists (created with its parents
    when ``create_dirs``) and accepts a new file, and ``path`` is not a folder. The check creates and removes a
    temporary file there, so it is true where permission bits are not (root, read-only mounts, ACLs)."""
    path = pathlib.Path(path)
    if path.is_dir():
        raise SSSInputError(f"{path}: output path is a directory")
    directory = path.parent if str(path.parent) else pathlib.Path(".")
    if create_dirs:
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SSSInputError(f"{directory}: cannot create the output directory ({exc.strerror})") from None
    if not directory.is_dir():
        raise SSSInputError(f"{directory}: " + ("a file, not an output directory" if directory.exists()
                                                else "output directory does not exist"))
    check_writable_folder(directory)
    return path


def _identity(path: pathlib.Path) -> str:
    return os.path.normcase(str(pathlib.Path(path).resolve()))


def output_problems(writes: list[tuple[str, pathlib.Path]], inputs: list[pathlib.Path]) -> list[str]:
    """What would lose a file, before anything is written: two writers (``(who, path)``) of one path, an output that
    is an input, by its name or under another (a hard link). Each problem a sentence naming the files."""
    by_name: dict[str, pathlib.Path] = {}
    by_file: dict[tuple[int, int], pathlib.Path] = {}  # a hard link is another path to one file
    for src in inputs:
        by_name.setdefault(_identity(src), src)
        with contextlib.suppress(OSError):
            st = pathlib.Path(src).stat()
            by_file.setdefault((st.st_dev, st.st_ino), src)
    writers: dict[str, list[tuple[str, pathlib.Path]]] = {}
    for who, out in writes:
        writers.setdefault(_identity(out), []).append((who, pathlib.Path(out)))
    problems = []
    for key, users in writers.items():
        if len(users) > 1:
            problems.append(f"{users[0][1]} would be written by " + " and ".join(w for w, _ in users))
        out = users[0][1]
        if key in by_name:
            problems.append(f"output {out} is the input {by_name[key]}: an input is never overwritten")
            continue
        with contextlib.suppress(OSError):
            st = out.stat()
            if (st.st_dev, st.st_ino) in by_file:
                problems.append(f"output {out} is the input {by_file[st.st_dev, st.st_ino]} under another name (a "
                                "hard link): an input is never overwritten")
    return problems


def check_output_folder(folder: pathlib.Path, flag: str) -> None:
    """Before any work: ``folder`` is a folder or can become one (its nearest existing ancestor is a folder that takes
    files): a path under a file, a read-only place or a pseudo filesystem is refused, naming ``flag``."""
    if folder.exists() and not folder.is_dir():
        raise SSSInputError(f"{flag} {folder} exists and is not a directory")
    place = folder.absolute()
    while not place.exists():
        place = place.parent
    if not place.is_dir():
        raise SSSInputError(f"{flag} {folder}: {place} is a file, not a directory")
    check_writable_folder(place)


def check_writable_folder(directory: pathlib.Path) -> None:
    """That ``directory`` (an existing folder) accepts a new file: a temporary created and removed there, so it is
    true where permission bits are not (root, read-only mounts, ACLs, pseudo filesystems)."""
    try:
        with tempfile.TemporaryFile(prefix=".sss_jax_probe.", dir=directory):
            pass
    except OSError as exc:
        raise SSSInputError(f"{directory}: output directory is not writable ({exc.strerror})") from None


def temporary_prefix(path: str | os.PathLike) -> str:
    """How ``atomic_path`` names the temporaries beside ``path``: ``.<name>.sss_jax-<host>-<pid>.<random>.tmp<ext>``,
    so a later run can tell the temporaries of a writer that is gone (SIGKILL) from those of one still writing."""
    return f".{pathlib.Path(path).name}.sss_jax-{socket.gethostname()}-{os.getpid()}."


_UMASK_STATUS = "/proc/self/status"
_UMASK_LOCK = threading.Lock()


def process_umask() -> int:
    """The process's umask, read without changing it where the system reports it (Linux 4.7+: the ``Umask:`` line of
    ``/proc/self/status``). ``os.umask`` reads it only by setting it, and while it is set every file another thread
    creates gets that mode: the batch's writer thread finishing a frame while its main thread opens the manifest, a
    caller's thread saving its own files. Elsewhere it is set for that moment to 077, so that a file created meanwhile
    is private rather than writable by everyone."""
    try:
        with open(_UMASK_STATUS, "rb") as f:
            for line in f:
                if line.startswith(b"Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:
        mask = os.umask(0o077)
        os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = True,
                verify: Callable[[pathlib.Path], bool] | None = None) -> Iterator[pathlib.Path]:
    """Yield a temporary path beside ``path``; on success flush it to the disk (fsync), check it with ``verify``
    (a writer that loses a failed write, as OpenImageIO's PNG writer does on a full disk, leaves a file that does
    not decode), move it into place and fsync the folder; on any failure remove it.

    ``overwrite=False`` places it only if ``path`` does not exist at that moment (a hard link, atomic across
    processes): a file another process created meanwhile is never replaced, an ``SSSInputError`` says so."""
    path = pathlib.Path(path)
    directory = path.parent if str(path.parent) else pathlib.Path(".")
    if not directory.is_dir():
        raise SSSInputError(f"{directory}: output directory does not exist")
    if not os.access(directory, os.W_OK):
        raise SSSInputError(f"{directory}: output directory is not writable")
    fd, tmp = tempfile.mkstemp(prefix=temporary_prefix(path), suffix=".tmp" + path.suffix, dir=directory)
    os.close(fd)
    tmp_path = pathlib.Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as f:
            os.fsync(f.fileno())
        if verify is not None and not verify(tmp_path):
            raise OSError(errno.EIO, f"{path}: the written file does not decode (disk full or an I/O error while "
                                     "writing); nothing was placed")
        # mkstemp creates 0600; a finished output gets the permissions an ordinary file would (0666 less umask)
        os.chmod(tmp_path, 0o666 & ~process_umask())
        if overwrite:
            os.replace(tmp_path, path)
        else:
            _place_new(tmp_path, path)
        with contextlib.suppress(OSError):  # the rename on the disk too (a folder fsync is not possible everywhere)
            dfd = os.open(directory, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def _place_new(tmp_path: pathlib.Path, path: pathlib.Path) -> None:
    """Move ``tmp_path`` to ``path`` only where ``path`` does not exist: ``link`` fails on an existing name, so two
    processes racing for one name cannot both win (``replace`` would let the second silently overwrite the first)."""
    try:
        os.link(tmp_path, path)
    except FileExistsError:
        raise SSSInputError(f"{path}: was created by another process while this one worked; not overwritten") from None
    except OSError as exc:  # a file system without hard links: the closest non-atomic equivalent
        if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EXDEV):
            raise
        if path.exists():
            raise SSSInputError(f"{path}: was created by another process while this one worked; not overwritten") \
                from None
        os.replace(tmp_path, path)
        return
    tmp_path.unlink()


def write_bytes_atomic(path: str | os.PathLike, data: bytes, *, overwrite: bool = True) -> pathlib.Path:
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return pathlib.Path(path)


def write_json_atomic(path: str | os.PathLike, obj: Any, *, indent: int = 1) -> pathlib.Path:
    text = json.dumps(obj, indent=indent, default=_json_default) + "\n"
    return write_bytes_atomic(path, text.encode())


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, pathlib.Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


# The standard EXR attributes an output takes from its input's header (``write_exr(like=...)``): what its pixels'
# colours mean (the primaries and white of an ACEScg or a P3 render; a compositor reads an EXR without them as
# Rec.709) and where its camera was (the projection a compositor's 3D tools read). Name: (number of floats,
# OpenImageIO's type).
CARRIED_ATTRIBUTES = {"chromaticities": (8, "float[8]"), "whiteLuminance": (1, "float"),
                      "adoptedNeutral": (2, "float2"), "worldToCamera": (16, "matrix"), "worldToNDC": (16, "matrix"),
                      "screenWindowCenter": (2, "float2"), "screenWindowWidth": (1, "float")}


def carried_attributes(header: Mapping[str, Any] | None) -> dict[str, tuple[float, ...]]:
    """The ``CARRIED_ATTRIBUTES`` a header (``Frame.metadata``: OpenImageIO's names) holds, as tuples of floats;
    one of another size or not numbers is left out."""
    out = {}
    for name, (size, _) in CARRIED_ATTRIBUTES.items():
        try:
            values = tuple(float(v) for v in np.ravel(np.asarray(header[name], np.float64)))
        except (KeyError, TypeError, ValueError):
            continue
        if len(values) == size:
            out[name] = values
    return out


def write_exr(
    path: str | os.PathLike,
    image: np.ndarray | Mapping[str, np.ndarray],
    *,
    channel_names: list[str] | None = None,
    half: bool = False,
    attributes: Mapping[str, Any] | None = None,
    overwrite: bool = True,
    window: Window | None = None,
    like: Mapping[str, Any] | None = None,
) -> pathlib.Path:
    """Write an ``(H, W, C)`` image (or a dict of named ``(H, W)`` channels) as a ZIP-compressed EXR, float32 or
    half, with ``attributes`` (str, int, float) in the header. Atomic; ``overwrite=False`` never replaces a file
    that exists when the write completes (see ``atomic_path``). ``window``: the data window's corner and the display
    window (``Frame.window`` of the frame the image came from: an overscan margin or a display window away from
    (0, 0) kept); None, both the image's at (0, 0). ``like``: the header of the frame the image came from
    (``Frame.metadata``): its ``CARRIED_ATTRIBUTES`` (colour primaries and white, camera matrices and screen window)
    are written too.

    The path must end in ``.exr``: the values are linear scene-referred floats, and another extension would make
    OpenImageIO write them into a format that means something else (an 8-bit PNG labelled sRGB holding linear
    values). ``write_png_preview`` writes display-encoded previews."""
    oiio = _oiio()
    if pathlib.Path(path).suffix.lower() != ".exr":
        raise SSSInputError(f"{path}: an EXR output needs the .exr extension (for an sRGB PNG preview use the "
                            "preview writer, --png on the command line)")
    if isinstance(image, Mapping):
        channel_names = list(image)
        arrays = [np.asarray(image[k], np.float32) for k in channel_names]
        if not arrays or any(a.shape != arrays[0].shape or a.ndim != 2 for a in arrays):
            raise SSSInputError(f"{path}: channels must all be (H, W) arrays of one shape")
        data = np.stack(arrays, axis=-1)
    else:
        data = np.asarray(image, np.float32)
        if data.ndim == 2:
            data = data[..., None]
        if data.ndim != 3:
            raise SSSInputError(f"{path}: image must be (H, W) or (H, W, C), got shape {data.shape}")
        if channel_names is None:
            channel_names = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(
                data.shape[-1], [f"C{i}" for i in range(data.shape[-1])])
    if len(channel_names) != data.shape[-1]:
        raise SSSInputError(f"{path}: {len(channel_names)} channel names for {data.shape[-1]} channels")
    if half:
        # beyond half's range a value would be written as inf, which poisons every filter and blend downstream:
        # written as half's largest, and said
        over = np.isfinite(data) & (np.abs(data) > _HALF_MAX)
        if over.any():
            largest = float(np.abs(data[over]).max())
            warnings.warn(f"{path}: {int(over.sum())} value(s) beyond half's range (up to {largest:.3g}) written as "
                          f"+-{_HALF_MAX:g}, half's largest; a float output keeps them", HalfRangeWarning,
                          stacklevel=2)
            data = np.where(over, np.sign(data) * _HALF_MAX, data)
    pixels = np.ascontiguousarray(data.astype(np.float16 if half else np.float32, copy=False))
    attributes = {key: _header_value(value) for key, value in (attributes or {}).items()}
    h, w, c = data.shape
    if window is not None and window.plain((h, w)):
        window = None
    if window is not None and (window.display[2] < 1 or window.display[3] < 1):
        raise SSSInputError(f"{path}: display window {window.display[2]}x{window.display[3]} is empty")
    carried = carried_attributes(like) if like is not None else {}
    if _openexr() is not None and len(set(channel_names)) == len(channel_names) and \
            all(_exr_attribute(k, v) for k, v in attributes.items()):
        return _write_scanline_exr(path, pixels, channel_names, attributes, overwrite, window, carried)
    spec = oiio.ImageSpec(w, h, c, oiio.HALF if half else oiio.FLOAT)
    if window is not None:
        spec.x, spec.y = window.x, window.y
        spec.full_x, spec.full_y, spec.full_width, spec.full_height = window.display
    spec.channelnames = tuple(channel_names)
    spec.attribute("compression", "zip")
    for key, value in attributes.items():
        spec.attribute(key, value)
    for key, values in carried.items():
        spec.attribute(key, oiio.TypeDesc(CARRIED_ATTRIBUTES[key][1]), values if len(values) > 1 else values[0])
    # checked from the file's chunk table, not decoded: the write's own errors are caught (write_image, close), and
    # what a lost write leaves (a chunk missing, misplaced or cut short) shows in the table at a fraction of a decode
    with atomic_path(path, overwrite=overwrite, verify=exr_chunks_complete) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise SSSInputError(f"{path}: cannot open for writing ({oiio.geterror()})")
        closed = False
        try:
            ok = out.write_image(pixels)
        finally:
            closed = out.close()
        if not (ok and closed):
            raise SSSInputError(f"{path}: write failed ({out.geterror()})")
    return pathlib.Path(path)


def _header_value(value: Any) -> int | float | str:
    """A header attribute's value as both writers store it: an int (a bool as 0 or 1), a float, or its text."""
    if isinstance(value, (bool, np.bool_, int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    return str(value)


def _exr_attribute(key: str, value: int | float | str) -> bool:
    """Whether OpenEXR's binding writes this header attribute (``_header_value``'s) as OpenImageIO would: a
    namespaced name outside OpenImageIO's own namespaces (OpenImageIO maps names such as ``DateTime`` or
    ``Copyright`` to the EXR standard attributes), an int only where it fits an EXR int."""
    prefix, colon, _ = key.partition(":")
    if not colon or prefix.lower() in ("oiio", "openexr", "exr"):
        return False
    return not isinstance(value, int) or -2**31 <= value < 2**31


def _write_scanline_exr(path, pixels: np.ndarray, channel_names: list[str],
                        attributes: Mapping[str, int | float | str], overwrite: bool,
                        window: Window | None = None,
                        carried: Mapping[str, tuple[float, ...]] | None = None) -> pathlib.Path:
    """``write_exr`` through OpenEXR's binding: the same file OpenImageIO writes (ZIP, scan lines, increasing y, the
    attributes with their types, the time of the write as ``capDate``, which OpenImageIO calls ``DateTime``, the
    windows)."""
    exr = _openexr()
    header: dict[str, Any] = {"compression": exr.ZIP_COMPRESSION, "type": exr.scanlineimage,
                              "capDate": time.strftime("%Y:%m:%d %H:%M:%S"), **attributes}
    for key, values in (carried or {}).items():  # the binding's types: a tuple (chromaticities), arrays, a float
        header[key] = values if key == "chromaticities" else values[0] if len(values) == 1 else \
            np.asarray(values, np.float32).reshape((4, 4) if len(values) == 16 else (-1,))
    if window is not None:  # OpenEXR's boxes: (min, max) corners, both inclusive
        h, w = pixels.shape[:2]
        dx, dy, dw, dh = window.display
        header["dataWindow"] = (np.array([window.x, window.y], np.int32),
                                np.array([window.x + w - 1, window.y + h - 1], np.int32))
        header["displayWindow"] = (np.array([dx, dy], np.int32), np.array([dx + dw - 1, dy + dh - 1], np.int32))
    planes = {name: np.ascontiguousarray(pixels[..., c]) for c, name in enumerate(channel_names)}
    with atomic_path(path, overwrite=overwrite, verify=exr_chunks_complete) as tmp:
        try:
            with exr.File(header, planes) as f:
                f.write(str(tmp))
        except Exception as exc:  # noqa: BLE001 - OpenEXR raises RuntimeError/OSError/ValueError as it sees fit
            raise SSSInputError(f"{path}: write failed ({exc})") from exc
    return pathlib.Path(path)


def display_transform(image: np.ndarray, *, exposure: float = 0.0, transform: str = "srgb") -> np.ndarray:
    """Linear scene-referred RGB -> display-referred sRGB in [0, 1]: exposure (stops), then ``"srgb"`` (clip) or
    ``"filmic"`` (Reinhard ``x / (1 + x)`` on luminance-preserving RGB), then the exact piecewise sRGB OETF
    (IEC 61966-2-1: ``12.92 x`` below 0.0031308, else ``1.055 x^(1/2.4) - 0.055``)."""
    x = np.nan_to_num(np.asarray(image, np.float64), nan=0.0, posinf=0.0, neginf=0.0) * 2.0**exposure
    x = np.maximum(x, 0.0)
    if transform == "filmic":
        x = x / (1 + x)
    elif transform != "srgb":
        raise ValueError(f"transform={transform!r} is not one of ('srgb', 'filmic')")
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def png_attribute(path: str | os.PathLike, name: str) -> str | None:
    """A text attribute of a PNG (``write_png_preview``'s ``attributes``), or None where the file has none or
    cannot be read as an image."""
    inp = _oiio().ImageInput.open(str(path))
    if inp is None:
        return None
    try:
        value = inp.spec().getattribute(name)
    finally:
        inp.close()
    return value if isinstance(value, str) else None


def write_png_preview(path: str | os.PathLike, image: np.ndarray, *, exposure: float = 0.0,
                      transform: str = "srgb", overwrite: bool = True,
                      attributes: Mapping[str, str] | None = None) -> pathlib.Path:
    """An 8-bit sRGB PNG preview of a linear image through ``display_transform`` (display-encoded with the sRGB
    transfer function, and labelled sRGB in the file), with ``attributes`` as text chunks. Atomic."""
    oiio = _oiio()
    if pathlib.Path(path).suffix.lower() != ".png":
        raise SSSInputError(f"{path}: a PNG preview needs the .png extension")
    disp = display_transform(image, exposure=exposure, transform=transform)
    if disp.ndim == 2:
        disp = disp[..., None]
    data = np.round(disp * 255).astype(np.uint8)
    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
    spec.attribute("oiio:ColorSpace", "sRGB")  # the values went through the sRGB OETF above: the label is true
    for name, value in (attributes or {}).items():
        spec.attribute(name, str(value))
    with atomic_path(path, overwrite=overwrite, verify=exr_is_complete) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise SSSInputError(f"{path}: cannot open for writing ({oiio.geterror()})")
        try:
            ok = out.write_image(np.ascontiguousarray(data))
        finally:
            out.close()
        if not ok:
            raise SSSInputError(f"{path}: write failed ({out.geterror()})")
    return pathlib.Path(path)
