"""Spherical-video metadata: marking an MP4/MOV file as a 360° equirectangular mono video.

A stitched panorama video is an ordinary 2:1 video until its file says otherwise: players (VLC, mpv,
headset players) and video sites (YouTube, Facebook) show it as a flat rectangle unless the video
track carries Google's spherical-video metadata. :func:`inject_spherical` writes both versions of it,
as Google's spatial-media specification defines them, into a file FFmpeg's mov muxer wrote (through
PyAV: ``ftyp``, ``mdat`` and ``moov``, with ``moov`` last, or first under ``movflags=faststart``):

- **V1** (``spherical-video-rfc.md``): a ``uuid`` box appended to the video track's ``trak``, holding
  the GSpherical RDF/XML: spherical, stitched, the stitching software, equirectangular. Older players
  and YouTube's ingest read it.
- **V2** (``spherical-video-v2-rfc.md``): ``st3d`` (mono) and ``sv3d`` (``svhd``, then ``proj`` with
  ``prhd`` and ``equi``) appended to the children of the video track's sample entry. FFmpeg, ExoPlayer
  and current players read it.

Existing spherical metadata (the V1 ``uuid``, ``st3d``, ``sv3d``) is replaced, so a second call
rewrites the same bytes: injecting is idempotent. Only ``moov`` is rewritten; the media data is copied
as it is. When ``moov`` lies before the media data, every chunk offset (``stco``/``co64``) that points
past it is shifted by the bytes it grew.

Convention (box layout written; sizes are big-endian, every ancestor's size updated)::

    moov/trak (each video track, handler 'vide')
      mdia/minf/stbl/stsd/<avc1|avc3|hvc1|hev1|vp09|av01|mp4v>  78 bytes of visual fields, then
        ...existing children (avcC, btrt, ...)
        st3d  full box: stereo_mode u8 = 0 (mono)
        sv3d
          svhd  full box: metadata source, UTF-8, NUL-terminated
          proj
            prhd  full box: pose yaw, pitch, roll, 16.16 fixed degrees = 0, 0, 0
            equi  full box: bounds top, bottom, left, right, 0.32 fixed = 0, 0, 0, 0
      ...existing children (tkhd, edts, mdia, ...)
      uuid  ffcc8263-f855-4a93-8814-587a02521fdd, then the GSpherical XML (V1)
"""

from __future__ import annotations

import os
import stat
import struct
import tempfile
import uuid
from dataclasses import dataclass
from os import PathLike
from typing import BinaryIO
from xml.sax.saxutils import escape

from rigjax.errors import RigjaxError

__all__ = ["SphericalError", "inject_spherical"]

_V1_UUID = uuid.UUID("ffcc8263-f855-4a93-8814-587a02521fdd").bytes
_VISUAL_ENTRIES = frozenset({b"avc1", b"avc3", b"hvc1", b"hev1", b"vp09", b"av01", b"mp4v"})
_FIRST_BOXES = frozenset(
    {b"ftyp", b"moov", b"mdat", b"wide", b"free", b"skip", b"pnot"}
)  # a file's first box: MP4's ftyp, or QuickTime's
_VISUAL_FIELDS = 78  # reserved, data_reference_index, ..., compressorname, depth, pre_defined
# bytes before the first child, for the boxes on the path to the sample entries and chunk offsets
_BEFORE_CHILDREN = {
    **dict.fromkeys((b"moov", b"trak", b"mdia", b"minf", b"stbl"), 0),
    b"stsd": 8,  # version and flags, entry count
    **dict.fromkeys(_VISUAL_ENTRIES, _VISUAL_FIELDS),
}


class SphericalError(RigjaxError):
    """A file that cannot be marked as a spherical video; the message names the file and says why."""


@dataclass
class _Box:
    """A box of ``moov``: its type, the bytes before its children (``stsd``'s version and count, a
    sample entry's visual fields; all of a leaf) and, for the boxes on the path, its children."""

    kind: bytes
    head: bytes
    children: list[_Box] | None = None
    tail: bytes = b""  # bytes after the last child that are not a box (QuickTime's 4 zero bytes)
    large: bool = False

    def find(self, *kinds: bytes) -> list[_Box]:
        return [child for child in self.children or [] if child.kind in kinds]

    def serialise(self) -> bytes:
        body = self.head + b"".join(child.serialise() for child in self.children or []) + self.tail
        if self.large or len(body) + 8 > 0xFFFFFFFF:
            return struct.pack(">I4sQ", 1, self.kind, len(body) + 16) + body
        return struct.pack(">I4s", len(body) + 8, self.kind) + body


@dataclass(frozen=True)
class _Extent:
    """A top-level box of the file: its type, where it starts and its whole length with its header."""

    kind: bytes
    start: int
    length: int
    header: int = 8  # 16 for a 64-bit largesize


def _top_level(f: BinaryIO, path: str) -> list[_Extent]:
    """The top-level boxes of an open file; :class:`SphericalError` unless they tile it exactly."""
    end, extents, start = f.seek(0, os.SEEK_END), [], 0
    while start < end:
        f.seek(start)
        raw = f.read(16)
        size, kind = struct.unpack(">I4s", raw[:8]) if len(raw) >= 8 else (0, b"")
        header = 16 if size == 1 and len(raw) == 16 else 8
        size = struct.unpack(">Q", raw[8:16])[0] if header == 16 else end - start if size == 0 else size
        known = kind in _FIRST_BOXES or bool(extents) and all(0x20 <= c < 0x7F for c in kind)
        if len(raw) < 8 or not known or size < header:
            raise SphericalError(f"{path}: not an MP4/MOV file (no valid box at byte {start})")
        if start + size > end:
            raise SphericalError(
                f"{path}: box {kind.decode()!r} at byte {start} runs past the end of the file "
                f"({size} bytes, {end - start} left); is the file truncated?"
            )
        extents.append(_Extent(kind, start, size, header))
        start += size
    return extents


def _parse(data: bytes, kind: bytes, large: bool = False) -> _Box:
    """The box ``kind`` from its body, its children parsed along the path to the sample entries."""
    head = _BEFORE_CHILDREN.get(kind)
    if head is None or len(data) < head:
        return _Box(kind, data, large=large)
    box, at = _Box(kind, data[:head], [], large=large), head
    while at + 8 <= len(data):
        size, child = struct.unpack(">I4s", data[at : at + 8])
        header = 16 if size == 1 else 8
        size = struct.unpack(">Q", data[at + 8 : at + 16])[0] if size == 1 else len(data) - at if size == 0 else size
        if size < header or at + size > len(data):
            break
        box.children.append(_parse(data[at + header : at + size], child, header == 16))
        at += size
    box.tail = data[at:]
    return box


def _spherical_boxes(software: str) -> tuple[_Box, _Box, _Box]:
    """The V1 ``uuid`` box for the ``trak`` and the V2 ``st3d`` and ``sv3d`` for the sample entry."""
    xml = (
        '<?xml version="1.0"?><rdf:SphericalVideo\n'
        'xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"\n'
        'xmlns:GSpherical="http://ns.google.com/videos/1.0/spherical/">'
        "<GSpherical:Spherical>true</GSpherical:Spherical>"
        "<GSpherical:Stitched>true</GSpherical:Stitched>"
        f"<GSpherical:StitchingSoftware>{escape(software)}</GSpherical:StitchingSoftware>"
        "<GSpherical:ProjectionType>equirectangular</GSpherical:ProjectionType>"
        "</rdf:SphericalVideo>"
    )
    full = bytes(4)  # version 0, flags 0
    svhd = _Box(b"svhd", full + software.encode() + b"\0")
    prhd = _Box(b"prhd", full + struct.pack(">iii", 0, 0, 0))  # yaw, pitch, roll (16.16 degrees)
    equi = _Box(b"equi", full + struct.pack(">IIII", 0, 0, 0, 0))  # top, bottom, left, right (0.32)
    sv3d = _Box(b"sv3d", b"", [svhd, _Box(b"proj", b"", [prhd, equi])])
    return _Box(b"uuid", _V1_UUID + xml.encode()), _Box(b"st3d", full + b"\0"), sv3d


def _mark_tracks(moov: _Box, software: str, path: str) -> None:
    """Replace any spherical metadata of every video track of ``moov`` by the metadata of ``software``."""
    uuid_box, st3d, sv3d = _spherical_boxes(software)
    tracks = [trak for trak in moov.find(b"trak") if _handler(trak) == b"vide"]
    if not tracks:
        raise SphericalError(f"{path}: no video track (no trak whose handler is 'vide')")
    for trak in tracks:
        entries = [
            entry for stbl in _sample_tables(trak) for stsd in stbl.find(b"stsd") for entry in stsd.children or []
        ]
        unsupported = [e.kind.decode("latin-1") for e in entries if e.children is None]
        if not entries:
            raise SphericalError(f"{path}: a video track without a sample entry (empty or missing stsd)")
        if unsupported:
            raise SphericalError(
                f"{path}: unsupported video sample entry {unsupported}; "
                f"expected one of {sorted(k.decode() for k in _VISUAL_ENTRIES)}"
            )
        for entry in entries:
            entry.children = [c for c in entry.children or [] if c.kind not in (b"st3d", b"sv3d")] + [st3d, sv3d]
        trak.children = [c for c in trak.children or [] if not _is_v1(c)] + [uuid_box]


def _handler(trak: _Box) -> bytes:
    """The handler type of a ``trak`` (``vide``, ``soun``, ...), from ``mdia/hdlr``."""
    hdlrs = [h for m in trak.find(b"mdia") for h in m.find(b"hdlr")]
    return hdlrs[0].head[8:12] if hdlrs else b""


def _sample_tables(trak: _Box) -> list[_Box]:
    """The ``mdia/minf/stbl`` of a ``trak``: its sample entries and chunk offsets."""
    return [stbl for mdia in trak.find(b"mdia") for minf in mdia.find(b"minf") for stbl in minf.find(b"stbl")]


def _is_v1(box: _Box) -> bool:
    """Whether ``box`` is a V1 spherical ``uuid`` box."""
    return box.kind == b"uuid" and box.head[:16] == _V1_UUID


def _shift_chunks(moov: _Box, after: int, delta: int, path: str) -> None:
    """Add ``delta`` to every chunk offset of ``moov`` at or past byte ``after`` of the original file:
    the media data behind a ``moov`` that grew by ``delta`` bytes."""
    tables = [
        table for trak in moov.find(b"trak") for stbl in _sample_tables(trak) for table in stbl.find(b"stco", b"co64")
    ]
    for table in tables:
        code = "I" if table.kind == b"stco" else "Q"  # 32-bit or 64-bit offsets
        (count,) = struct.unpack(">I", table.head[4:8])  # after version and flags
        end = 8 + count * struct.calcsize(code)
        offsets = [o + delta if o >= after else o for o in struct.unpack(f">{count}{code}", table.head[8:end])]
        if code == "I" and max(offsets, default=0) > 0xFFFFFFFF:
            raise SphericalError(
                f"{path}: a chunk offset would pass 4 GiB once moov grows by {delta} bytes, and stco is 32-bit"
            )
        table.head = table.head[:8] + struct.pack(f">{count}{code}", *offsets) + table.head[end:]


def inject_spherical(path: str | PathLike[str], *, software: str = "learnstitch") -> None:
    """Mark the MP4/MOV file ``path`` as a 360° equirectangular mono video (V1 and V2 metadata).

    The file is rewritten atomically (a temporary file in its folder, synced, then renamed over it);
    any spherical metadata already there is replaced. :class:`SphericalError`, the file untouched, when
    it is not an MP4/MOV box structure, has no or several ``moov``, is fragmented, has no video track
    or a video sample entry other than those listed in the module's Convention.
    """
    path = os.fspath(path)
    if "\0" in software:  # svhd's string ends at the first NUL
        raise SphericalError(f"{path}: the software name {software!r} contains a NUL character")
    if not os.path.isfile(path):
        raise SphericalError(f"{path}: no such file")
    with open(path, "rb") as src:
        extents = _top_level(src, path)
        moovs = [e for e in extents if e.kind == b"moov"]
        if len(moovs) != 1:
            raise SphericalError(f"{path}: {len(moovs)} moov boxes; expected one (an MP4/MOV file its writer closed)")
        if any(e.kind == b"moof" for e in extents):
            raise SphericalError(f"{path}: a fragmented MP4 (moof boxes), which this writer does not rewrite")
        old = moovs[0]
        src.seek(old.start + old.header)
        moov = _parse(src.read(old.length - old.header), b"moov", old.header == 16)
        _mark_tracks(moov, software, path)
        _shift_chunks(moov, old.start + old.length, len(moov.serialise()) - old.length, path)
        _write_atomically(path, src, extents, moov.serialise())


def _write_atomically(path: str, src: BinaryIO, extents: list[_Extent], moov: bytes) -> None:
    """Write ``src``'s top-level boxes, ``moov`` replaced, to a temporary file, then rename it over ``path``."""
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), prefix=".spherical-", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as dst:
            for extent in extents:
                if extent.kind == b"moov":
                    dst.write(moov)
                    continue
                src.seek(extent.start)
                _copy_range(src, dst, extent.length, path)
            dst.flush()
            os.fsync(dst.fileno())
        os.chmod(tmp, stat.S_IMODE(os.stat(path).st_mode))
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def _copy_range(src: BinaryIO, dst: BinaryIO, length: int, path: str, chunk: int = 1 << 20) -> None:
    """Copy ``length`` bytes from ``src``'s position to ``dst``, a block at a time (``mdat`` may be GiBs)."""
    while length > 0:
        block = src.read(min(chunk, length))
        if not block:
            raise SphericalError(f"{path}: the file ended while it was copied (did it change meanwhile?)")
        dst.write(block)
        length -= len(block)
