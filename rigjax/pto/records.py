"""The line types of a ``.pto`` project that rigjax interprets: ``p``, ``i``, ``v``, ``c`` and ``k``.

Each has a parser (text -> typed value, errors naming file, line and token) and a renderer (typed
value -> text). A renderer given the line it was parsed from rewrites only the tokens whose value
changed, so unknown tokens and Hugin's own spelling of unchanged numbers survive a round trip.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ..camera.projections import SUPPORTED_PROJECTIONS
from ..errors import RigjaxError
from .tokens import Where, format_number, join_tokens, parse_float, parse_int, parse_string, quoted, split_tokens

# .pto letter -> rigjax.Image field, for the variables of an i line rigjax reads (all linkable).
IMAGE_FIELDS: dict[str, str] = {
    "v": "hfov",
    "a": "a",
    "b": "b",
    "c": "c",
    "d": "d",
    "e": "e",
    "g": "g",
    "t": "t",
    "y": "yaw",
    "p": "pitch",
    "r": "roll",
    "TrX": "trans_x",
    "TrY": "trans_y",
    "TrZ": "trans_z",
    "Tpy": "trans_plane_yaw",
    "Tpp": "trans_plane_pitch",
    # Hugin's photometric model (rigjax.camera.photometry): exposure value, white balance, radial
    # vignetting and its centre's shift
    "Eev": "exposure_value",
    "Er": "white_balance_red",
    "Eb": "white_balance_blue",
    "Va": "vignetting_a",
    "Vb": "vignetting_b",
    "Vc": "vignetting_c",
    "Vd": "vignetting_d",
    "Vx": "vignetting_x",
    "Vy": "vignetting_y",
}
# Hugin's defaults for letters missing from an i line (PTScriptParsing.cpp ImgInfo::defaultValues).
IMAGE_DEFAULTS: dict[str, float] = {letter: 0.0 for letter in IMAGE_FIELDS} | {
    "v": 51.0,
    "Er": 1.0,
    "Eb": 1.0,
    "Va": 1.0,
}


@dataclass(frozen=True)
class Image:
    """One ``i`` line: image size, lens type, the geometric variables and Hugin's photometric ones
    (``IMAGE_FIELDS``; the camera response ``Ra``..``Re`` and the vignetting mode ``Vm`` are kept as
    written).

    ``links`` maps a letter (``"v"``, ``"b"``, ...) to the image whose value this image shares; the
    value stored here is already the shared one.
    """

    width: int
    height: int
    projection: int
    hfov: float = 51.0
    a: float = 0.0
    b: float = 0.0
    c: float = 0.0
    d: float = 0.0
    e: float = 0.0
    g: float = 0.0
    t: float = 0.0
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    trans_x: float = 0.0
    trans_y: float = 0.0
    trans_z: float = 0.0
    trans_plane_yaw: float = 0.0
    trans_plane_pitch: float = 0.0
    exposure_value: float = 0.0  # Eev: the exposure is 2^-Eev
    white_balance_red: float = 1.0  # Er, Eb: the red and blue channels' factors
    white_balance_blue: float = 1.0
    vignetting_a: float = 1.0  # Va..Vd: Va + Vb r^2 + Vc r^4 + Vd r^6
    vignetting_b: float = 0.0
    vignetting_c: float = 0.0
    vignetting_d: float = 0.0
    vignetting_x: float = 0.0  # Vx, Vy: the vignetting centre's shift from the image centre, px
    vignetting_y: float = 0.0
    # S l,r,t,b: the part of the image that holds the picture, Hugin's crop (from column l to r, row
    # t to b; it may reach beyond the frame): a circular fisheye's (f2, and f8, f20 as Hugin has it:
    # circular_crop) is the circle inscribed in it, centred in it, of half its shorter side; other
    # lenses' the rectangle. None: no crop (an empty one reads as none, as in Hugin).
    crop: tuple[int, int, int, int] | None = None
    filename: str = ""
    links: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.crop is not None:
            crop = tuple(self.crop)
            if len(crop) != 4 or any(float(v) != int(v) for v in crop):
                raise RigjaxError(f"crop: expected (left, right, top, bottom) whole pixels, got {self.crop!r}")
            crop = tuple(int(v) for v in crop)
            if not (crop[0] < crop[1] and crop[2] < crop[3]):
                raise RigjaxError(f"crop: expected left < right and top < bottom, got {crop!r}")
            object.__setattr__(self, "crop", crop)

    @property
    def circular_crop(self) -> bool:
        """Whether the crop is the circle inscribed in it (:func:`crop_circle`), as Hugin draws a
        circular fisheye's: lens types f2, f8 and f20 (Hugin's ``SrcPanoImage::isCircularCrop``)."""
        return self.projection in _CIRCULAR_CROP

    def value(self, letter: str) -> float:
        """The value of a ``.pto`` letter (``"v"``, ``"y"``, ``"TrX"``, ...)."""
        return getattr(self, IMAGE_FIELDS[letter])

    def replace(self, **changes: Any) -> Image:
        return dataclasses.replace(self, **changes)


# Photometric variables: valid in v lines, not geometry.
PHOTOMETRIC_VARIABLES = frozenset({"Eev", "Er", "Eb", "Ra", "Rb", "Rc", "Rd", "Re", "Va", "Vb", "Vc", "Vd", "Vx", "Vy"})
# The i-line tokens of more than one letter rigjax reads, by first letter ("Eev" before "Eb", "Er").
_MULTI_LETTER = {
    "T": ("TrX", "TrY", "TrZ", "Tpy", "Tpp"),
    "E": ("Eev", "Er", "Eb"),
    "V": ("Va", "Vb", "Vc", "Vd", "Vx", "Vy"),
}
_SINGLE_LETTER = frozenset("whfvabcdegtypr" + "n" + "S" + "C")
# Lens types whose crop Hugin draws as the circle inscribed in it.
_CIRCULAR_CROP = frozenset({2, 8, 20})
_VARIABLE = re.compile(r"([A-Za-z]+)(\d*)")


# ---------------------------------------------------------------------------------------------
# p line
@dataclass(frozen=True)
class PanoramaLine:
    """The ``p`` line's geometry: projection code (2 = equirectangular), size in px, hfov in degrees;
    and its exposure value ``E`` (the panorama's exposure is 2^-E, :mod:`rigjax.camera.photometry`).

    The other tokens (output format, crop ...) are kept verbatim by the project.
    """

    width: int
    height: int
    hfov: float = 360.0
    projection: int = 2
    exposure_value: float = 0.0


def parse_panorama_line(line: str, where: Where) -> tuple[PanoramaLine, Any]:
    tokens, seps = split_tokens(line, where)
    values: dict[str, Any] = {}
    for token in tokens[1:]:
        letter, text = token[:1], token[1:]
        if not letter or letter not in "fwhvE":
            continue
        if letter in values:
            raise where.error(f"{letter!r} is given twice", token)
        if letter == "v":
            values[letter] = parse_float(text, token, where, "panorama hfov 'v'")
        elif letter == "E":
            values[letter] = parse_float(text, token, where, "panorama exposure value 'E'")
        else:
            values[letter] = parse_int(
                text,
                token,
                where,
                {"f": "panorama projection 'f'", "w": "panorama width 'w'", "h": "panorama height 'h'"}[letter],
            )
    missing = [letter for letter in "fwhv" if letter not in values]
    if missing:
        raise where.error(f"the panorama line has no {', '.join(repr(m) for m in missing)}")
    if values["w"] <= 0 or values["h"] <= 0 or values["v"] <= 0:
        raise where.error(f"panorama size and hfov must be positive (w{values['w']} h{values['h']} v{values['v']})")
    pano = PanoramaLine(
        width=values["w"],
        height=values["h"],
        hfov=values["v"],
        projection=values["f"],
        exposure_value=values.get("E", 0.0),
    )
    return pano, (tokens, seps, pano)


def render_panorama_line(pano: PanoramaLine, source: Any) -> str:
    current = {
        "f": str(pano.projection),
        "w": str(pano.width),
        "h": str(pano.height),
        "v": format_number(pano.hfov),
        "E": format_number(pano.exposure_value),
    }
    if source is None:
        return (
            f"p f{current['f']} w{current['w']} h{current['h']} v{current['v']}  k0 E{current['E']} R0 "
            'n"TIFF_m c:LZW r:CROP"'
        )
    tokens, seps, original = source
    if original == pano:
        return join_tokens(tokens, seps)
    tokens, seps = list(tokens), list(seps)
    for idx, token in enumerate(tokens[1:], start=1):
        if token[:1] in current:
            tokens[idx] = token[0] + current[token[0]]
    if "E" not in {token[:1] for token in tokens[1:]} and pano.exposure_value != 0.0:
        tokens.append("E" + current["E"])
        seps.insert(len(seps) - 1, " ")  # before it; the line's trailing space stays last
    return join_tokens(tokens, seps)


# ---------------------------------------------------------------------------------------------
# i line
def classify_image_token(token: str) -> str | None:
    """The letter of an ``i``-line token that rigjax interprets, or ``None`` (kept verbatim)."""
    names = _MULTI_LETTER.get(token[:1])
    if names is not None:
        return next((name for name in names if token.startswith(name)), None)
    return token[0] if token[:1] in _SINGLE_LETTER else None


def parse_image_line(line: str, where: Where) -> tuple[dict[str, Any], tuple[list[str], list[str]]]:
    """Parse an ``i`` line into ``{letter: value}``; links are ``("link", K, token)``."""
    tokens, seps = split_tokens(line, where)
    values: dict[str, Any] = {}
    for token in tokens[1:]:
        letter = classify_image_token(token)
        if letter is None:
            continue
        if letter in values:
            raise where.error(f"{letter!r} is given twice", token)
        text = token[len(letter) :]
        if letter == "n":
            values[letter] = parse_string(text, token, where, "the file name 'n'")
        elif letter in "SC":  # C: libpano's cut frame, which Hugin reads as S (S first where both are)
            values[letter] = _parse_crop(text, token, where)
        elif letter in "whf":
            what = {"w": "image width 'w'", "h": "image height 'h'", "f": "lens type 'f'"}[letter]
            values[letter] = parse_int(text, token, where, what)
            if letter in "wh" and values[letter] <= 0:
                raise where.error(f"{what} must be positive", token)
        elif text.startswith("="):
            values[letter] = ("link", parse_int(text[1:], token, where, f"the link of {letter!r}"), token)
        else:
            values[letter] = parse_float(text, token, where, f"{letter!r} ({IMAGE_FIELDS[letter]})")
            if letter == "v" and values[letter] <= 0.0:
                raise where.error(f"'v' (hfov) must be positive, found {text!r}", token)
    if "f" in values:
        if values["f"] not in SUPPORTED_PROJECTIONS:
            token = next(t for t in tokens if classify_image_token(t) == "f")
            raise where.error(
                f"unknown lens type f{values['f']} (supported: {', '.join(f'f{p}' for p in SUPPORTED_PROJECTIONS)})",
                token,
            )
    return values, (tokens, seps)


def _parse_crop(text: str, token: str, where: Where) -> tuple[int, int, int, int] | None:
    """A crop's ``l,r,t,b`` (whole pixels); an empty one (left >= right or top >= bottom) is none,
    as Hugin reads it (the token is kept as written)."""
    parts = text.split(",")
    if len(parts) != 4:
        raise where.error(f"the crop {token[0]!r} takes left,right,top,bottom, found {text!r}", token)
    left, right, top, bottom = (parse_int(part, token, where, f"the crop {token[0]!r}") for part in parts)
    return (left, right, top, bottom) if left < right and top < bottom else None


def crop_circle(crop: tuple[int, int, int, int]) -> tuple[float, float, float]:
    """The circle a circular fisheye's crop ``(left, right, top, bottom)`` (:attr:`Image.crop`)
    bounds, as Hugin takes it: centre ``((left + right) / 2, (top + bottom) / 2)`` and radius half
    the crop's shorter side, pixels."""
    left, right, top, bottom = crop
    return (left + right) / 2.0, (top + bottom) / 2.0, min(right - left, bottom - top) / 2.0


def _crop_token(crop: tuple[int, int, int, int]) -> str:
    return "S" + ",".join(str(int(v)) for v in crop)


def _image_token(image: Image, letter: str) -> str:
    if letter in image.links:
        return f"{letter}={image.links[letter]}"
    return letter + format_number(image.value(letter))


def render_image_line(image: Image, source: Any) -> str:
    """Render an ``i`` line; ``source`` is ``(tokens, seps, image_as_loaded)`` or ``None``."""
    if source is None:
        t = lambda letter: _image_token(image, letter)  # noqa: E731
        return (
            f"i w{image.width} h{image.height} f{image.projection} {t('v')} Ra0 Rb0 Rc0 Rd0 Re0 "
            f"{t('Eev')} {t('Er')} {t('Eb')} "
            f"{t('r')} {t('p')} {t('y')} {t('TrX')} {t('TrY')} {t('TrZ')} {t('Tpy')} {t('Tpp')} j0 "
            f"{t('a')} {t('b')} {t('c')} {t('d')} {t('e')} {t('g')} {t('t')} "
            f"{t('Va')} {t('Vb')} {t('Vc')} {t('Vd')} {t('Vx')} {t('Vy')} "
            + ("" if image.crop is None else f" {_crop_token(image.crop)}")
            + " Vm5 n"
            + quoted(image.filename, "file name")
        )
    tokens, seps, original = source
    tokens, seps = list(tokens), list(seps)
    present: set[str] = set()
    for idx, token in enumerate(tokens[1:], start=1):
        letter = classify_image_token(token)
        if letter is None:
            continue
        present.add(letter)
        if letter in IMAGE_FIELDS:
            same = image.value(letter) == original.value(letter) and image.links.get(letter) == original.links.get(
                letter
            )
            if not same:
                tokens[idx] = _image_token(image, letter)
        elif letter == "w" and image.width != original.width:
            tokens[idx] = f"w{image.width}"
        elif letter == "h" and image.height != original.height:
            tokens[idx] = f"h{image.height}"
        elif letter == "f" and image.projection != original.projection:
            tokens[idx] = f"f{image.projection}"
        elif letter == "n" and image.filename != original.filename:
            tokens[idx] = "n" + quoted(image.filename, "file name")
        elif letter in "SC" and image.crop != original.crop:  # the first crop token becomes the new S
            tokens[idx] = "" if image.crop is None or {"S", "C"} & present - {letter} else _crop_token(image.crop)
    missing = [
        _image_token(image, letter)
        for letter in IMAGE_FIELDS
        if letter not in present and (letter in image.links or image.value(letter) != IMAGE_DEFAULTS[letter])
    ]
    if not {"S", "C"} & present and image.crop is not None:
        missing.append(_crop_token(image.crop))
    if "n" not in present and image.filename:
        missing.append("n" + quoted(image.filename, "file name"))
    for token in missing:  # before the file name, where Hugin puts its variables
        at = next((i for i, tok in enumerate(tokens) if tok.startswith('n"')), len(tokens))
        tokens.insert(at, token)
        seps.insert(at, " ")  # the separator before the new token; the old one now follows it
    while "" in tokens:  # a crop taken away: its token and the separator before it
        at = tokens.index("")
        del tokens[at], seps[at]
    return join_tokens(tokens, seps)


# ---------------------------------------------------------------------------------------------
# v lines
class OptVariable(NamedTuple):
    """A ``v``-line entry: the optimiser may change letter ``name`` of image ``image``."""

    name: str
    image: int

    def __str__(self) -> str:
        return f"{self.name}{self.image}"


def parse_variable_line(line: str, where: Where) -> list[tuple[OptVariable, Where, str]]:
    tokens, _ = split_tokens(line, where)
    out = []
    for token in tokens[1:]:
        match = _VARIABLE.fullmatch(token)
        if not match:
            raise where.error("a variable is a letter and an image number, like 'v0' or 'y1'", token)
        name, number = match.groups()
        if name not in IMAGE_FIELDS and name not in PHOTOMETRIC_VARIABLES:
            raise where.error(f"unknown variable {name!r}", token)
        # A bare letter means image 0 (PTGui compatibility, as Hugin reads it).
        image = parse_int(number, token, where, f"the image number of {name!r}") if number else 0
        out.append((OptVariable(name, image), where, token))
    return out


def render_variables(variables: tuple[OptVariable, ...]) -> list[str]:
    """One variable per line and a closing bare ``v``, as Hugin writes them."""
    return [f"v {var}" for var in variables] + ["v"]


# ---------------------------------------------------------------------------------------------
# c lines
@dataclass(frozen=True, eq=False)
class ControlPoints:
    """All control points of a project as arrays (``n`` points).

    Convention: ``xy_a`` is in image ``image_a`` and ``xy_b`` in image ``image_b``, both in Hugin
    pixel coordinates of the full image (pixel centres at integers). ``kind`` is the ``t`` token:
    0 normal, 1 vertical line, 2 horizontal line, 3 and up points on one straight line.
    ``extra`` holds each line's tokens that rigjax does not interpret (usually ``""``).
    """

    image_a: np.ndarray
    image_b: np.ndarray
    xy_a: np.ndarray
    xy_b: np.ndarray
    kind: np.ndarray
    extra: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        n = len(np.asarray(self.image_a))
        object.__setattr__(self, "image_a", np.asarray(self.image_a, dtype=np.int64).reshape(n))
        object.__setattr__(self, "image_b", np.asarray(self.image_b, dtype=np.int64).reshape(n))
        object.__setattr__(self, "xy_a", np.asarray(self.xy_a, dtype=np.float64).reshape(n, 2))
        object.__setattr__(self, "xy_b", np.asarray(self.xy_b, dtype=np.float64).reshape(n, 2))
        object.__setattr__(self, "kind", np.asarray(self.kind, dtype=np.int64).reshape(n))
        if not self.extra:
            object.__setattr__(self, "extra", ("",) * n)
        if len(self.extra) != n:
            raise ValueError(f"extra has {len(self.extra)} entries for {n} control points")

    def __len__(self) -> int:
        return len(self.image_a)

    @classmethod
    def empty(cls) -> ControlPoints:
        return cls(np.zeros(0), np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))

    @classmethod
    def from_pairs(cls, pairs) -> ControlPoints:
        """Normal (``t0``) points from pairs' matches ``(a, b, xy_a, xy_b)``: pixels of image ``a`` and
        their matches in image ``b``, pair after pair."""
        pairs = list(pairs)
        if not pairs:
            return cls.empty()
        return cls(
            np.concatenate([np.full(len(xy_a), a) for a, _, xy_a, _ in pairs]),
            np.concatenate([np.full(len(xy_a), b) for _, b, xy_a, _ in pairs]),
            np.concatenate([xy_a for *_, xy_a, _ in pairs]),
            np.concatenate([xy_b for *_, xy_b in pairs]),
            np.zeros(sum(len(xy_a) for _, _, xy_a, _ in pairs)),
        )

    @classmethod
    def from_rows(cls, rows: list[tuple]) -> ControlPoints:
        if not rows:
            return cls.empty()
        a, b, x, y, X, Y, t, extra, _ = zip(*rows)
        return cls(np.array(a), np.array(b), np.stack([x, y], -1), np.stack([X, Y], -1), np.array(t), tuple(extra))

    def equals(self, other: ControlPoints) -> bool:
        return (
            len(self) == len(other)
            and all(
                np.array_equal(getattr(self, f), getattr(other, f))
                for f in ("image_a", "image_b", "xy_a", "xy_b", "kind")
            )
            and self.extra == other.extra
        )


def parse_control_point(line: str, where: Where) -> tuple:
    tokens, _ = split_tokens(line, where)
    values: dict[str, Any] = {}
    extra: list[str] = []
    names = {
        "n": "first image 'n'",
        "N": "second image 'N'",
        "x": "'x'",
        "y": "'y'",
        "X": "'X'",
        "Y": "'Y'",
        "t": "type 't'",
    }
    for token in tokens[1:]:
        letter = token[:1]
        if letter not in names:
            extra.append(token)
            continue
        if letter in values:
            raise where.error(f"{letter!r} is given twice", token)
        parse = parse_int if letter in "nNt" else parse_float
        values[letter] = parse(token[1:], token, where, names[letter])
    missing = [letter for letter in "nNxyXY" if letter not in values]
    if missing:
        raise where.error(f"the control point has no {', '.join(repr(m) for m in missing)}")
    return (
        values["n"],
        values["N"],
        values["x"],
        values["y"],
        values["X"],
        values["Y"],
        values.get("t", 0),
        " ".join(extra),
        where,
    )


def render_control_points(cps: ControlPoints) -> list[str]:
    f = format_number
    lines = []
    for k in range(len(cps)):
        line = (
            f"c n{cps.image_a[k]} N{cps.image_b[k]} x{f(cps.xy_a[k, 0])} y{f(cps.xy_a[k, 1])} "
            f"X{f(cps.xy_b[k, 0])} Y{f(cps.xy_b[k, 1])} t{cps.kind[k]}"
        )
        lines.append(line + (" " + cps.extra[k] if cps.extra[k] else ""))
    return lines


# ---------------------------------------------------------------------------------------------
# k lines
@dataclass(frozen=True, eq=False)
class Mask:
    """A ``k`` line: a polygon (image pixels) of image ``image``; ``kind`` 0 exclude, 1 include,
    2 stack-exclude, 3 stack-include, 4 lens-exclude."""

    image: int
    kind: int
    polygon: np.ndarray

    def equals(self, other: Mask) -> bool:
        return self.image == other.image and self.kind == other.kind and np.array_equal(self.polygon, other.polygon)


def parse_mask(line: str, where: Where) -> Mask:
    tokens, _ = split_tokens(line, where)
    values: dict[str, Any] = {}
    for token in tokens[1:]:
        letter = token[:1]
        if letter == "i":
            values["i"] = parse_int(token[1:], token, where, "mask image 'i'")
        elif letter == "t":
            values["t"] = parse_int(token[1:], token, where, "mask type 't'")
        elif letter == "p":
            text = parse_string(token[1:], token, where, "mask polygon 'p'")
            numbers = [parse_float(v, token, where, "mask polygon 'p'") for v in text.split()]
            if len(numbers) % 2:
                raise where.error("a mask polygon needs pairs of coordinates", token)
            values["p"] = np.array(numbers, dtype=np.float64).reshape(-1, 2)
    missing = [letter for letter in "itp" if letter not in values]
    if missing:
        raise where.error(f"the mask has no {', '.join(repr(m) for m in missing)}")
    return Mask(values["i"], values["t"], values["p"])


def render_mask(mask: Mask) -> str:
    points = " ".join(format_number(v) for v in mask.polygon.reshape(-1))
    return f'k i{mask.image} t{mask.kind} p"{points}"'


# ---------------------------------------------------------------------------------------------
# rigjax's own lines: comments to Hugin (which drops them when it saves a project).
#
#   #-rigjax centre 1 0.346410161513775 0 -0.2        camera 1's centre, x y z (rig frame)
#   #-rigjax sd 1 v0.17 y0.012 p0.0102 r0.0113        standard deviations of camera 1's letters
#   #-rigjax sd 0 vfree y0.05 p0.04 r0.04             'free': the matches leave the letter undetermined
#
# Hugin's own translation (TrX, TrY, TrZ) moves a camera relative to one plane (Tpy, Tpp) that
# every point is taken to lie on; a 360-degree rig's scene is on no one plane, so the centres are
# kept in these lines and the i-lines' Tr* stay as they are (docs/rigjax/guide.md).
RIGJAX_PREFIX = "#-rigjax "
RIGJAX_RECORDS = ("centre", "sd")
SD_LETTERS = "vabcdeypr"  # the columns of a deviations array (rigjax.optimiser.objective.LETTERS)
SD_FREE = "free"  # an infinite standard deviation: the letter's value is undetermined


def parse_rigjax_line(line: str, where: Where) -> tuple[str, int, np.ndarray]:
    """``(kind, image, values)`` of a ``#-rigjax`` line: a centre's ``(3,)`` coordinates, or an
    ``sd`` line's ``(9,)`` deviations (letters ``vabcdeypr``, NaN where not given, ``inf`` where
    ``free``)."""
    tokens, _ = split_tokens(line[len(RIGJAX_PREFIX) :], where)
    kind = tokens[0]  # one of RIGJAX_RECORDS: other '#-rigjax' lines (pruned points) stay as they are
    if len(tokens) < 2:
        raise where.error(f"'#-rigjax {kind}' needs an image number")
    image = parse_int(tokens[1], tokens[1], where, f"the image number of a '#-rigjax {kind}' line")
    if kind == "centre":
        if len(tokens) != 5:
            raise where.error(f"'#-rigjax centre' needs an image number and x y z, found {len(tokens) - 2} values")
        values = np.array([parse_float(t, t, where, "a centre coordinate") for t in tokens[2:]])
    else:
        values = np.full(len(SD_LETTERS), np.nan)
        for token in tokens[2:]:
            letter = token[:1]
            if letter not in SD_LETTERS or not np.isnan(values[SD_LETTERS.index(letter)]):
                raise where.error(f"a standard deviation is one of {', '.join(SD_LETTERS)}, each once", token)
            if token[1:] == SD_FREE:
                values[SD_LETTERS.index(letter)] = np.inf
                continue
            value = parse_float(token[1:], token, where, f"the standard deviation of {letter!r}")
            if value < 0:
                raise where.error(f"a standard deviation is >= 0, found {token!r}", token)
            values[SD_LETTERS.index(letter)] = value
    return kind, image, values


def render_rigjax_lines(kind: str, values: np.ndarray) -> list[str]:
    """The ``#-rigjax`` lines of an ``(n_images, 3)`` centres or ``(n_images, 9)`` deviations array."""
    lines = []
    for k, row in enumerate(np.asarray(values, float)):
        if kind == "centre":
            fields = [format_number(float(v)) for v in row]
        else:
            fields = [
                f"{letter}{SD_FREE if v == np.inf else format_number(float(v))}"
                for letter, v in zip(SD_LETTERS, row)
                if not np.isnan(v)
            ]
        lines.append(" ".join([RIGJAX_PREFIX + kind, str(k), *fields]))
    return lines
