"""Hugin ``.pto`` projects: typed records for what rigjax uses, everything else kept verbatim.

A :class:`Project` holds the panorama line (``p``), the images (``i``), the control points (``c``),
the optimiser's variables (``v``) and the masks (``k``) as typed values. It also remembers every
line of the file it came from: :meth:`Project.save` writes uninterpreted lines and tokens back
unchanged, and interpreted tokens whose value did not change exactly as they were read, so a
user's project never loses data. New values are written with 15 significant digits, as Hugin does.

Lens links (``v=0``) are resolved on load: every image holds the value it uses, and
``Image.links`` names the image whose value it shares (the lowest-numbered of its link group,
which is what Hugin writes). On save rigjax writes ``#hugin_optimizerMasterSwitch 0`` and
``#hugin_optimizerPhotoMasterSwitch 0`` so that Hugin honours the ``v`` lines (reference §4.5).
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from typing import Any, NamedTuple

import numpy as np

from ..errors import PtoError, RigjaxError, UnsupportedError
from .records import (
    IMAGE_DEFAULTS,
    IMAGE_FIELDS,
    RIGJAX_PREFIX,
    RIGJAX_RECORDS,
    ControlPoints,
    Image,
    Mask,
    OptVariable,
    PanoramaLine,
    parse_control_point,
    parse_image_line,
    parse_mask,
    parse_panorama_line,
    parse_rigjax_line,
    parse_variable_line,
    render_control_points,
    render_image_line,
    render_mask,
    render_panorama_line,
    render_rigjax_lines,
    render_variables,
)
from .tokens import Where, parse_int

_UNMODELLED = ("g", "t", "TrX", "TrY", "TrZ", "Tpy", "Tpp")

_SWITCHES = ("#hugin_optimizerMasterSwitch", "#hugin_optimizerPhotoMasterSwitch")


class _Source(NamedTuple):
    """What a parsed record looked like in the file, to write unchanged tokens back verbatim."""

    tokens: list[str]
    seps: list[str]
    parsed: Any  # the record as loaded (an Image)


@dataclass(frozen=True, eq=False)
class Project:
    """A Hugin project. Build one with :func:`load_project`, :func:`parse_project` or :meth:`new`.

    Attributes:
        panorama: the ``p`` line.
        images: the ``i`` lines, in order (image numbers are indices into this tuple).
        control_points: all ``c`` lines as arrays.
        variables: the ``v`` lines: which letter of which image the optimiser may change.
        masks: the ``k`` lines.
        optimizer_switch: ``#hugin_optimizerMasterSwitch`` as read (Hugin lets a non-zero switch,
            an optimiser preset, override the ``v`` lines). Written back as read while the ``v``
            lines are unchanged; as 0 once they changed.
        path: the file this project was read from, if any.
        centres: ``(n_images, 3)`` camera centres in the rig frame (x right, y down, z forward;
            the user's unit), or None: rigjax's ``#-rigjax centre`` lines, which Hugin keeps as
            comments (:mod:`rigjax.pto.records`). The rotation-only objectives do not use them.
        deviations: ``(n_images, 9)`` standard deviations of the letters ``vabcdeypr`` (NaN where
            not estimated) from a bundle adjustment, or None: ``#-rigjax sd`` lines.
    """

    panorama: PanoramaLine
    images: tuple[Image, ...]
    control_points: ControlPoints
    variables: tuple[OptVariable, ...] = ()
    masks: tuple[Mask, ...] = ()
    optimizer_switch: int = 0
    path: str | None = None
    centres: np.ndarray | None = None
    deviations: np.ndarray | None = None
    _layout: tuple[tuple, ...] = field(default=(), repr=False)
    _sources: Mapping[str, Any] = field(default_factory=dict, repr=False)

    # ----------------------------------------------------------------------------------------
    @classmethod
    def new(
        cls,
        panorama: PanoramaLine,
        images: Sequence[Image],
        control_points: ControlPoints | None = None,
        variables: Sequence[OptVariable] = (),
        masks: Sequence[Mask] = (),
    ) -> Project:
        """A project written from scratch, laid out as Hugin 2022 writes its files."""
        images = tuple(images)
        project = cls(
            panorama=panorama,
            images=images,
            control_points=control_points if control_points is not None else ControlPoints.empty(),
            variables=tuple(OptVariable(*v) for v in variables),
            masks=tuple(masks),
        )
        _check_references(project)
        return project

    def replace(self, **changes: Any) -> Project:
        """A copy with some fields replaced; the file layout is kept."""
        project = dataclasses.replace(self, **changes)
        _check_references(project)
        return project

    def with_comment_lines(self, lines: Sequence[str]) -> Project:
        """A copy that writes ``lines`` (each starting with ``#``) right after the control points."""
        for line in lines:
            if not line.startswith("#") or "\n" in line:
                raise RigjaxError(f"a comment line must start with '#' and be one line, got {line!r}")
        layout = list(self._layout or _default_layout(self))
        kinds = [entry[0] for entry in layout]
        at = len(layout) - kinds[::-1].index("c") if "c" in kinds else len(layout)
        layout[at:at] = [("raw", line) for line in lines]
        return dataclasses.replace(self, _layout=tuple(layout))

    # ----------------------------------------------------------------------------------------
    def cameras(self, dtype=None, host: bool = False):
        """The images as one batched :class:`rigjax.Camera` (fields of shape ``(n_images,)``;
        NumPy arrays if ``host``).

        Raises :class:`UnsupportedError` for lens types or variables (shear ``g``/``t``, the
        translation ``Tr*``/``Tp*``) that the camera model does not cover.
        """
        import jax.numpy as jnp

        from ..camera.model import Camera
        from ..camera.projections import SUPPORTED_PROJECTIONS

        for k, image in enumerate(self.images):
            if image.projection not in SUPPORTED_PROJECTIONS:
                raise UnsupportedError(
                    f"image {k}: lens type f{image.projection} is not supported "
                    f"(supported: {', '.join(f'f{p}' for p in SUPPORTED_PROJECTIONS)})"
                )
            for letter in _UNMODELLED:
                if image.value(letter) != 0.0:
                    raise UnsupportedError(
                        f"image {k}: {letter}={image.value(letter)!r} is not modelled by rigjax "
                        f"(only 0 is supported for {', '.join(_UNMODELLED)})"
                    )

        def column(name):
            return np.array([getattr(image, name) for image in self.images])

        return Camera.create(
            projection=column("projection"),
            width=column("width"),
            height=column("height"),
            hfov=column("hfov"),
            a=column("a"),
            b=column("b"),
            c=column("c"),
            d=column("d"),
            e=column("e"),
            yaw=column("yaw"),
            pitch=column("pitch"),
            roll=column("roll"),
            dtype=dtype,
            xp=np if host else jnp,
        )

    def with_cameras(self, cameras) -> Project:
        """A copy whose images take hfov, a-e and yaw/pitch/roll from a batched :class:`Camera`.

        Linked images must receive identical values (the optimiser shares one parameter per link
        group); a mismatch is an error rather than a silent choice.
        """
        names = {letter: IMAGE_FIELDS[letter] for letter in ("v", "a", "b", "c", "d", "e", "y", "p", "r")}
        columns = {letter: np.asarray(getattr(cameras, name), dtype=float) for letter, name in names.items()}
        for letter, values in columns.items():
            if values.shape != (len(self.images),):
                raise RigjaxError(
                    f"camera field {names[letter]!r} has shape {values.shape}, expected ({len(self.images)},)"
                )
            bad = np.flatnonzero(~np.isfinite(values) | ((values <= 0.0) if letter == "v" else False))
            if bad.size:
                k = int(bad[0])
                raise RigjaxError(
                    f"image {k}: camera field {names[letter]!r} is {values[k]!r}; a project holds finite numbers "
                    "(and a positive hfov)"
                )
        images = []
        for k, image in enumerate(self.images):
            changes = {names[letter]: float(columns[letter][k]) for letter in names}
            for letter, root in image.links.items():
                if letter in names and columns[letter][k] != columns[letter][root]:
                    raise RigjaxError(
                        f"image {k} links {letter!r} to image {root}, but the cameras give "
                        f"{columns[letter][k]!r} and {columns[letter][root]!r}"
                    )
            images.append(image.replace(**changes))
        return self.replace(images=tuple(images))

    def canvas(self, dtype=None, host: bool = False):
        """The panorama canvas as a :class:`rigjax.Equirect`; the ``p`` line must be equirectangular.

        Hugin rounds an odd equirectangular width up to the next even number when it reads a
        project (``PanoramaOptions::setWidth``); the canvas does the same, so coordinates agree
        with Hugin's. The ``p`` line itself is written back as it was read.
        """
        import jax.numpy as jnp

        from ..camera.panorama import Equirect

        if self.panorama.projection != 2:
            raise UnsupportedError(
                f"panorama projection f{self.panorama.projection} is not supported: "
                "rigjax maps to equirectangular panoramas (p f2) only"
            )
        width = self.panorama.width + self.panorama.width % 2
        return Equirect.create(width, self.panorama.height, self.panorama.hfov, dtype=dtype, xp=np if host else jnp)

    # ----------------------------------------------------------------------------------------
    def to_text(self) -> str:
        """The project as ``.pto`` text (what :meth:`save` writes)."""
        layout = self._layout or _default_layout(self)
        out: list[str] = []
        n_image_entries = sum(1 for entry in layout if entry[0] == "i")
        n_mask_entries = sum(1 for entry in layout if entry[0] == "k")
        switches_written: set[str] = set()
        for entry in layout:
            kind = entry[0]
            if kind == "raw":
                out.append(entry[1])
            elif kind == "p":
                out.append(render_panorama_line(self.panorama, self._sources.get("p")))
            elif kind == "i":
                k = entry[1]
                if k < len(self.images):
                    out.append(render_image_line(self.images[k], self._image_source(k)))
                if k == n_image_entries - 1:  # images added after loading follow the last one
                    out.extend(render_image_line(image, None) for image in self.images[n_image_entries:])
                    out.extend(self._new_rigjax_lines(layout))
            elif kind == "v":  # unchanged: each line in its place; changed: all at the first's
                source = self._sources.get("v")
                if source is not None and source[1] == self.variables:
                    out.append(source[0][entry[1]])
                elif entry[1] == 0:
                    out.extend(render_variables(self.variables))
            elif kind == "c":
                source = self._sources.get("c")
                if source is not None and source[1].equals(self.control_points):
                    out.append(source[0][entry[1]])
                elif entry[1] == 0:
                    out.extend(render_control_points(self.control_points))
            elif kind == "k":
                k = entry[1]
                if k < len(self.masks):
                    source = self._sources.get("k", {}).get(k)
                    same = source is not None and source[1].equals(self.masks[k])
                    out.append(source[0] if same else render_mask(self.masks[k]))
                if k == n_mask_entries - 1:
                    out.extend(render_mask(m) for m in self.masks[n_mask_entries:])
            elif kind == "rigjax":
                name, index = entry[1], entry[2]
                values = self._rigjax_values(name)
                source = self._sources.get("rigjax", {}).get(name)
                if source is not None and values is not None and _same(source[1], values):
                    out.append(source[0][index])
                elif index == 0 and values is not None:
                    out.extend(render_rigjax_lines(name, values))
            elif kind == "switch":
                out.append(self._switch_line(*entry[1:]))
                switches_written.add(entry[1])
        # Records whose kind the file did not have yet go at the end, so nothing added is lost.
        kinds = {entry[0] for entry in layout}
        if "i" not in kinds:
            out.extend(render_image_line(image, None) for image in self.images)
            out.extend(self._new_rigjax_lines(layout))
        if "v" not in kinds and self.variables:
            out.extend(render_variables(self.variables))
        if "c" not in kinds and len(self.control_points):
            out.extend(render_control_points(self.control_points))
        if "k" not in kinds:
            out.extend(render_mask(m) for m in self.masks)
        out.extend(f"{name} 0" for name in _SWITCHES if name not in switches_written)
        return "\n".join(out) + "\n"

    def _rigjax_values(self, kind: str) -> np.ndarray | None:
        return self.centres if kind == "centre" else self.deviations

    def _new_rigjax_lines(self, layout: tuple[tuple, ...]) -> list[str]:
        """``#-rigjax`` lines of values the file had no lines for: after the image lines."""
        had = {entry[1] for entry in layout if entry[0] == "rigjax"}
        lines = []
        for kind in ("centre", "sd"):
            values = self._rigjax_values(kind)
            if values is not None and kind not in had:
                lines.extend(render_rigjax_lines(kind, values))
        return lines

    def _switch_line(self, name: str, line: str | None = None) -> str:
        """A Hugin optimiser switch as read while the ``v`` lines are as read (the user's preset
        stays); 0 once they changed, so that Hugin optimises what the ``v`` lines say."""
        source = self._sources.get("v")
        loaded = source[1] if source is not None else ()
        if self.variables != loaded:
            return f"{name} 0"
        if name == _SWITCHES[0] and self.optimizer_switch != self._sources.get("switch", 0):
            return f"{name} {self.optimizer_switch}"
        return line if line is not None else f"{name} 0"

    def save(self, path: str | PathLike[str]) -> None:
        """Write the project atomically (a temporary file renamed over ``path``)."""
        path = os.fspath(path)
        text = self.to_text()
        directory = os.path.dirname(os.path.abspath(path))
        fd, tmp = tempfile.mkstemp(prefix=".rigjax-", suffix=".pto", dir=directory)
        try:
            with os.fdopen(fd, "w", encoding="utf-8", errors="surrogateescape", newline="\n") as f:
                f.write(text)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)  # mkstemp's file is private; a project is an ordinary file
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise

    def _image_source(self, k: int) -> _Source | None:
        sources = self._sources.get("i", ())
        return sources[k] if k < len(sources) else None


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return np.shape(a) == np.shape(b) and bool(np.array_equal(a, b, equal_nan=True))


# ---------------------------------------------------------------------------------------------
def load_project(path: str | PathLike[str]) -> Project:
    """Read a Hugin ``.pto`` project. Errors name the file, the line and the token."""
    path = os.fspath(path)
    try:
        # newline="": lines are split by the parser, as parse_project splits text, so that a file
        # and its text read alike (universal newlines would turn a lone "\r" into a line break).
        with open(path, encoding="utf-8", errors="surrogateescape", newline="") as f:
            text = f.read()
    except OSError as exc:
        raise PtoError(f"cannot read the project: {exc.strerror}", path=path) from exc
    return parse_project(text, path=path)


@contextlib.contextmanager
def _cyclic_gc_paused():
    """Parsing builds a few containers per token and no reference cycles: the cyclic collector's
    passes over the growing heap find nothing and, run every few hundred allocations, make reading
    a large project superlinear in its size."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


@dataclass
class _Lines:
    """A ``.pto`` file's lines sorted by record as :func:`parse_project` reads them: each record's
    parsed value with where it was (for errors) and its line (to write it back), and ``layout``,
    each line's place in the file."""

    path: str | None
    layout: list[tuple] = field(default_factory=list)
    panorama: PanoramaLine | None = None
    p_source: Any = None
    image_lines: list[tuple[Where, dict[str, Any], tuple]] = field(default_factory=list)
    cp_rows: list[tuple] = field(default_factory=list)
    cp_lines: list[str] = field(default_factory=list)
    var_lines: list[str] = field(default_factory=list)
    variables: list[tuple[OptVariable, Where, str]] = field(default_factory=list)
    masks: list[tuple[Mask, Where, str]] = field(default_factory=list)
    rigjax_lines: dict[str, list[tuple[int, np.ndarray, Where, str]]] = field(default_factory=dict)
    switch: int = 0


@_cyclic_gc_paused()
def parse_project(text: str, path: str | PathLike[str] | None = None) -> Project:
    """Parse ``.pto`` text (see :func:`load_project`)."""
    lines = _read_lines(text, None if path is None else os.fspath(path))
    if lines.panorama is None:
        raise PtoError("no panorama line ('p f2 w... h... v...')", path=lines.path)
    images = _resolve_links(lines.image_lines)
    n = len(images)
    control_points = ControlPoints.from_rows(lines.cp_rows)
    _check_image_numbers(lines, n)
    rigjax = {kind: _rigjax_values(kind, rows, n) for kind, rows in lines.rigjax_lines.items()}
    sources = {
        "rigjax": {
            kind: (tuple(row[3] for row in lines.rigjax_lines[kind]), values) for kind, values in rigjax.items()
        },
        "p": lines.p_source,
        "i": tuple(_Source(tokens, seps, image) for (_, _, (tokens, seps)), image in zip(lines.image_lines, images)),
        "v": (tuple(lines.var_lines), tuple(v for v, _, _ in lines.variables)),
        "c": (tuple(lines.cp_lines), control_points),
        "k": {k: (line, mask) for k, (mask, _, line) in enumerate(lines.masks)},
        "switch": lines.switch,
    }
    return Project(
        panorama=lines.panorama,
        images=images,
        control_points=control_points,
        variables=tuple(v for v, _, _ in lines.variables),
        masks=tuple(m for m, _, _ in lines.masks),
        optimizer_switch=lines.switch,
        path=lines.path,
        centres=rigjax.get("centre"),
        deviations=rigjax.get("sd"),
        _layout=tuple(lines.layout),
        _sources=sources,
    )


def _read_lines(text: str, path: str | None) -> _Lines:
    """Every line of ``.pto`` text parsed into its record (:class:`_Lines`); an error names the
    file (``path``), the line and the token."""
    lines = _Lines(path)
    for number, line in enumerate(text.split("\n"), start=1):
        line = line.removesuffix("\r")  # \r\n line ends; any other \r is refused below
        where = Where(path, number)
        if "\r" in line:  # Hugin splits lines at "\n" only; a lone "\r" would be read two ways
            raise where.error("a carriage return (\\r) inside the line; lines end in \\n or \\r\\n")
        if number == 1 and line.startswith("# ptGui project file"):
            raise where.error("this is a PTGui script; save it from PTGui as a Hugin project (.pto)")
        _read_line(lines, line, where)
    # The split leaves an empty string after the final newline; it is written back by to_text.
    if lines.layout and lines.layout[-1] == ("raw", ""):
        lines.layout.pop()
    return lines


def _read_line(lines: _Lines, line: str, where: Where) -> None:
    """One line of a ``.pto`` file, parsed and added to ``lines`` by its kind."""
    kind = line[:1]
    record = line[1:2] in (" ", "")
    if kind == "p" and record:
        if lines.panorama is not None:
            raise where.error("a second 'p' line; a project has one panorama")
        lines.panorama, lines.p_source = parse_panorama_line(line, where)
        lines.layout.append(("p",))
    elif kind == "i" and record:
        values, (tokens, seps) = parse_image_line(line, where)
        lines.layout.append(("i", len(lines.image_lines)))
        lines.image_lines.append((where, values, (tokens, seps)))
    elif kind == "v" and record:
        lines.layout.append(("v", len(lines.var_lines)))  # each line's place: a file is written back as read
        lines.var_lines.append(line)
        lines.variables.extend(parse_variable_line(line, where))
    elif kind == "c" and record:
        lines.layout.append(("c", len(lines.cp_lines)))
        lines.cp_lines.append(line)
        lines.cp_rows.append(parse_control_point(line, where))
    elif kind == "k" and record:
        lines.layout.append(("k", len(lines.masks)))
        lines.masks.append((parse_mask(line, where), where, line))
    elif line.startswith(RIGJAX_PREFIX) and line[len(RIGJAX_PREFIX) :].split(" ", 1)[0] in RIGJAX_RECORDS:
        kind, image, values = parse_rigjax_line(line, where)
        records = lines.rigjax_lines.setdefault(kind, [])
        lines.layout.append(("rigjax", kind, len(records)))
        records.append((image, values, where, line))
    elif line.split(" ")[0] in _SWITCHES:
        name, _, value = line.partition(" ")
        if name == _SWITCHES[0]:
            lines.switch = parse_int(value.strip(), line, where, "the optimizer master switch")
        lines.layout.append(("switch", name, line))
    else:
        lines.layout.append(("raw", line))


def _check_image_numbers(lines: _Lines, n: int) -> None:
    """An error naming the line and token of the first control point, variable or mask that refers
    to an image the project's ``n`` images do not have."""
    for row in lines.cp_rows:
        where_cp = row[-1]
        for idx, letter in ((row[0], "n"), (row[1], "N")):
            if not 0 <= idx < n:
                raise where_cp.error(
                    f"control point refers to image {idx}, the project has {n} images", f"{letter}{idx}"
                )
    for var, where_v, token in lines.variables:
        if not 0 <= var.image < n:
            raise where_v.error(f"variable refers to image {var.image}, the project has {n} images", token)
    for mask, where_k, _ in lines.masks:
        if not 0 <= mask.image < n:
            raise where_k.error(f"mask refers to image {mask.image}, the project has {n} images", f"i{mask.image}")


def _rigjax_values(kind: str, rows: list[tuple[int, np.ndarray, Where, str]], n: int) -> np.ndarray:
    """The ``(n, m)`` array of a project's ``#-rigjax`` lines of one kind: one line per image."""
    values = np.full((n, len(rows[0][1])), np.nan)
    given = np.zeros(n, bool)
    for image, row, where, _ in rows:
        if not 0 <= image < n:
            raise where.error(f"'#-rigjax {kind}' refers to image {image}, the project has {n} images", str(image))
        if given[image]:
            raise where.error(f"a second '#-rigjax {kind}' line for image {image}", str(image))
        values[image], given[image] = row, True
    if not given.all():
        missing = int(np.flatnonzero(~given)[0])
        raise rows[0][2].error(
            f"'#-rigjax {kind}' lines give images {np.flatnonzero(given).tolist()} but not image {missing}"
        )
    return values


def _resolve_links(image_lines: list[tuple[Where, dict[str, Any], tuple]]) -> tuple[Image, ...]:
    """Resolve ``letter=K`` links: each link group shares the value of its one unlinked member.

    Links form a forest (each image links at most once per letter); the member that holds the
    value is the end of every chain, and a chain that returns to itself holds none (an error).
    """
    n = len(image_lines)
    targets: dict[str, dict[int, int]] = {}  # letter -> {image: the image it links to}
    resolved: list[dict[str, float]] = []
    for k, (where, values, _) in enumerate(image_lines):
        own = {}
        for letter, value in values.items():
            if letter in ("S", "C"):  # the crop, not a variable
                continue
            if isinstance(value, tuple):  # ("link", K, token)
                _, other, token = value
                if other == k:
                    raise where.error(f"image {k} links {letter!r} to itself", token)
                if not 0 <= other < n:
                    raise where.error(f"link to image {other}, the project has {n} images", token)
                targets.setdefault(letter, {})[k] = other
            elif letter in IMAGE_FIELDS:
                own[letter] = value
        resolved.append(IMAGE_DEFAULTS | own)
    links: list[dict[str, int]] = [{} for _ in range(n)]
    for letter, target in targets.items():
        groups: dict[int, list[int]] = {}
        holders: dict[int, int] = {}  # image -> the end of its chain, each found once: linear time
        for k in sorted(target):
            chain, on_chain, node = [], set(), k
            while node not in holders and node in target:
                if node in on_chain:
                    where, values, _ = image_lines[k]
                    raise where.error(
                        f"the links of {letter!r} form a cycle through images {sorted(on_chain)}", values[letter][2]
                    )
                chain.append(node)
                on_chain.add(node)
                node = target[node]
            holder = holders.get(node, node)
            holders.update(dict.fromkeys(chain, holder))
            resolved[k][letter] = resolved[holder][letter]
            groups.setdefault(holder, []).append(k)
        # Hugin writes a link as a reference to the lowest-numbered image of the group.
        for holder, linked in groups.items():
            members = sorted([holder, *linked])
            for k in members[1:]:
                links[k][letter] = members[0]
    images = []
    for k, (where, values, _) in enumerate(image_lines):
        for size in ("w", "h", "f"):
            if size not in values:
                raise where.error(f"the image line has no {size!r} (image {'size' if size != 'f' else 'lens type'})")
        fields = {IMAGE_FIELDS[letter]: value for letter, value in resolved[k].items()}
        images.append(
            Image(
                width=values["w"],
                height=values["h"],
                projection=values["f"],
                filename=values.get("n", ""),
                crop=values["S"] if "S" in values else values.get("C"),
                links=links[k],
                **fields,
            )
        )
    return tuple(images)


def _check_references(project: Project) -> None:
    n = len(project.images)
    cps = project.control_points
    for name, idx in (("image_a", cps.image_a), ("image_b", cps.image_b)):
        bad = np.flatnonzero((idx < 0) | (idx >= n))
        if bad.size:
            raise RigjaxError(f"control point {bad[0]} has {name}={idx[bad[0]]}, the project has {n} images")
    for var in project.variables:
        if not 0 <= var.image < n:
            raise RigjaxError(f"variable {var.name}{var.image} refers to a missing image ({n} images)")
    for k, image in enumerate(project.images):
        for letter, root in image.links.items():
            if not 0 <= root < k:
                raise RigjaxError(f"image {k} links {letter!r} to image {root}; links must point to a lower image")
    for name, width in (("centres", 3), ("deviations", 9)):
        values = getattr(project, name)
        if values is not None and np.shape(values) != (n, width):
            raise RigjaxError(f"{name} has shape {np.shape(values)}, expected ({n}, {width}): one row per image")
    if project.centres is not None and not np.all(np.isfinite(project.centres)):
        raise RigjaxError("centres must be finite numbers")


def _default_layout(project: Project) -> tuple[tuple, ...]:
    """Hugin 2022's file layout for a project written from scratch."""
    layout: list[tuple] = [
        ("raw", "# hugin project file"),
        ("raw", "#hugin_ptoversion 2"),
        ("p",),
        ("raw", "m i0"),
        ("raw", ""),
        ("raw", "# image lines"),
    ]
    layout += [("i", k) for k in range(len(project.images))]
    layout += [("raw", ""), ("raw", "# specify variables that should be optimized"), ("v", 0)]
    layout += [("raw", ""), ("raw", "# control points"), ("c", 0)]
    if project.masks:
        layout += [("raw", ""), ("raw", "# masks")] + [("k", k) for k in range(len(project.masks))]
    layout += [("raw", ""), ("raw", "#hugin_optimizeReferenceImage 0")]
    layout += [("switch", name) for name in _SWITCHES]
    return tuple(layout)
