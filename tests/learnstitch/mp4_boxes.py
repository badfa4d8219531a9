"""A minimal MP4/MOV box reader for the tests: what a player reads of spherical metadata.

Independent of :mod:`learnstitch.video.spherical` (no shared code): it walks the whole box tree of a
file, insisting that every container's children tile it exactly and the top-level boxes the file, and
reads the V1 GSpherical XML, the V2 ``st3d``/``sv3d`` boxes and the chunk offsets of every track.
"""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

SPHERICAL_UUID = bytes.fromhex("ffcc8263f8554a938814587a02521fdd")
GSPHERICAL = "{http://ns.google.com/videos/1.0/spherical/}"
RDF = "{http://www.w3.org/1999/02/22-rdf-syntax-ns#}"
VISUAL = ("avc1", "avc3", "hvc1", "hev1", "vp09", "av01", "mp4v", "jpeg")
# bytes between a container's header and its first child
SKIP = {
    **dict.fromkeys(("moov", "trak", "mdia", "minf", "stbl", "dinf", "edts", "udta", "sv3d", "proj"), 0),
    **dict.fromkeys(("stsd", "dref"), 8),  # version and flags, entry count
    **dict.fromkeys(VISUAL, 78),  # the visual sample entry's fields
}


@dataclass(frozen=True)
class Node:
    """A box: its type, where its header starts, its size with the header, where its body starts."""

    kind: str
    start: int
    size: int
    body: int
    children: tuple[Node, ...] = ()

    def all(self, kind: str) -> list[Node]:
        return [child for child in self.children if child.kind == kind]

    def path(self, *kinds: str) -> list[Node]:
        nodes = [self]
        for kind in kinds:
            nodes = [child for node in nodes for child in node.all(kind)]
        return nodes


def walk(data: bytes, start: int, end: int) -> tuple[Node, ...]:
    """The boxes tiling ``data[start:end]``; ``ValueError`` if they do not tile it exactly."""
    nodes, at = [], start
    while at < end:
        if at + 8 > end:
            raise ValueError(f"{end - at} stray bytes at {at}")
        size, kind = struct.unpack(">I4s", data[at : at + 8])
        header = 8
        if size == 1:
            size, header = struct.unpack(">Q", data[at + 8 : at + 16])[0], 16
        elif size == 0:
            size = end - at
        if size < header or at + size > end:
            raise ValueError(f"box {kind!r} at {at}: size {size} does not fit in its parent (ends at {end})")
        name = kind.decode("latin-1")
        body = at + header
        children = walk(data, body + SKIP[name], at + size) if name in SKIP else ()
        nodes.append(Node(name, at, size, body, children))
        at += size
    return tuple(nodes)


def read_tree(path: Path) -> tuple[bytes, Node]:
    """The file's bytes and a root node whose children are its top-level boxes."""
    data = Path(path).read_bytes()
    return data, Node("file", 0, len(data), 0, walk(data, 0, len(data)))


def video_tracks(root: Node, data: bytes) -> list[Node]:
    """The ``trak`` boxes whose ``mdia/hdlr`` handler type is ``vide``."""
    return [
        trak
        for trak in root.path("moov", "trak")
        if any(data[h.body + 8 : h.body + 12] == b"vide" for h in trak.path("mdia", "hdlr"))
    ]


def v1_fields(data: bytes, box: Node) -> dict[str, str]:
    """The GSpherical fields of a V1 ``uuid`` box, by local name (``Spherical``, ``ProjectionType``...)."""
    root = ET.fromstring(data[box.body + 16 : box.start + box.size])
    assert root.tag == f"{RDF}SphericalVideo", root.tag
    return {child.tag.removeprefix(GSPHERICAL): (child.text or "") for child in root}


def sv3d_fields(data: bytes, sv3d: Node) -> dict[str, object]:
    """``svhd``'s source, ``prhd``'s pose (yaw, pitch, roll in degrees) and ``equi``'s bounds (0.32)."""
    (svhd,) = sv3d.all("svhd")
    (prhd,) = sv3d.path("proj", "prhd")
    (equi,) = sv3d.path("proj", "equi")
    source = data[svhd.body + 4 : svhd.start + svhd.size]
    assert source.endswith(b"\0"), source
    pose = struct.unpack(">iii", data[prhd.body + 4 : prhd.body + 16])
    return {
        "source": source[:-1].decode(),
        "pose": tuple(value / 65536 for value in pose),
        "bounds": struct.unpack(">IIII", data[equi.body + 4 : equi.body + 20]),
        "versions": (data[svhd.body], data[prhd.body], data[equi.body]),
    }


def spherical(path: Path) -> list[dict[str, object]]:
    """Per video track: its sample entry's type, the V1 fields of each spherical ``uuid`` box in its
    ``trak``, each ``st3d``'s stereo mode and each ``sv3d``'s fields in its sample entries."""
    data, root = read_tree(path)
    tracks = []
    for trak in video_tracks(root, data):
        entries = [e for stsd in trak.path("mdia", "minf", "stbl", "stsd") for e in stsd.children]
        uuids = [u for u in trak.all("uuid") if data[u.body : u.body + 16] == SPHERICAL_UUID]
        tracks.append(
            {
                "entries": [e.kind for e in entries],
                "v1": [v1_fields(data, u) for u in uuids],
                "stereo_mode": [data[b.body + 4] for e in entries for b in e.all("st3d")],
                "sv3d": [sv3d_fields(data, b) for e in entries for b in e.all("sv3d")],
            }
        )
    return tracks


def chunk_tables(path: Path) -> list[Node]:
    """Every track's ``stco`` or ``co64`` box, in track order."""
    _, root = read_tree(path)
    stbls = root.path("moov", "trak", "mdia", "minf", "stbl")
    return [table for stbl in stbls for table in stbl.children if table.kind in ("stco", "co64")]


def chunk_offsets(path: Path) -> list[list[int]]:
    """Every track's chunk offsets (file positions of its samples' chunks), in track order."""
    data = Path(path).read_bytes()
    offsets = []
    for table in chunk_tables(path):
        (count,) = struct.unpack(">I", data[table.body + 4 : table.body + 8])
        code = f">{count}{'I' if table.kind == 'stco' else 'Q'}"
        offsets.append(list(struct.unpack(code, data[table.body + 8 : table.body + 8 + struct.calcsize(code)])))
    return offsets


def top_level(path: Path) -> list[str]:
    """The types of the file's top-level boxes, in order (``ftyp``, ``mdat``, ``moov``...)."""
    return [node.kind for node in read_tree(path)[1].children]
