"""Strict loading of TOML files into frozen, validated dataclasses.

Every parameter set, scenario, preset and suite in mpcasv is a frozen pydantic dataclass with
``extra="forbid"``: an unknown key, a missing field, a non-numeric value or an out-of-range
number is refused with a :class:`ConfigError` naming the file and the field, before anything
runs. Numbers are strict: ``"1.5"`` (a string) is not a number.
"""

from __future__ import annotations

import codecs
import dataclasses
import tomllib
import unicodedata
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import AfterValidator, ConfigDict, Field, Strict, TypeAdapter, ValidationError
from pydantic.dataclasses import dataclass as _pydantic_dataclass

T = TypeVar("T")


def between(lo: float, hi: float, unit: str = "", why: str = "", *, lo_open: bool = False,
            integer: bool = False) -> Any:
    """A number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``), given as a number (an integer
    with ``integer``), never as a string, a bool, nan or inf. Out of range it is refused with
    the range and ``why`` the bound is there: ``20000 m is outside the allowed range
    [0, 11000] m (the deepest ocean is 10.9 km)``."""
    u = f" {unit}" if unit else ""
    span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]{u}"
    because = f" ({why})" if why else ""

    def check(v: float) -> float:
        if v < lo or (lo_open and v == lo) or v > hi:
            raise ValueError(f"{v:g}{u} is outside the allowed range {span}{because}")
        return v

    if integer:
        return Annotated[int, Strict(), AfterValidator(check)]
    return Annotated[float, Strict(), Field(allow_inf_nan=False), AfterValidator(check)]


#: A finite real number given as a number (int or float), never as a string, a bool, nan or inf.
Float = Annotated[float, Strict(), Field(allow_inf_nan=False)]
#: A strictly positive finite number (inf in a speed or a weight was a traceback mid-run).
Pos = Annotated[float, Strict(), Field(gt=0, allow_inf_nan=False)]
#: A strictly positive number where inf means "none" (e.g. a time constant: no decay).
PosOrInf = Annotated[float, Strict(), Field(gt=0)]
#: A duration (s): finite and > 0 (inf would run for ever); the same as :data:`Pos`.
FinitePos = Pos
#: The longest simulated run (s): a week (``duration = 1e300`` was accepted and ran for ever)
DURATION_MAX = 7 * 86400.0
#: A run's duration (s): in ``(0, DURATION_MAX]``.
Duration = between(0, DURATION_MAX, "s", "a week at most", lo_open=True)

# The size of a scenario's world: bounds of every depth, AUV speed and horizontal coordinate
# or length a scenario file gives (docs/experiments.md, "Bounds"). A depth of 20000 m, a
# waypoint 1e9 m down and a lawnmower leg of 1e12 m were accepted.
#: The deepest depth (m): the deepest ocean (Challenger Deep, 10.9 km), rounded up.
DEPTH_MAX = 11000.0
#: The fastest AUV (m/s): about 10 knots, twice the fastest survey AUVs (the LAUV's 2 m/s,
#: REMUS 600 and HUGIN 2.5-3 m/s) and beyond what an ASV accompanies (Gretha: 2.5 m/s).
AUV_SPEED_MAX = 5.0
#: The farthest anything in a run can go (m): the fastest AUV for the longest run, 3024 km.
#: Every horizontal coordinate (``|N|``, ``|E|``) and length of a scenario lies within it.
DISTANCE_MAX = AUV_SPEED_MAX * DURATION_MAX
#: The most AUVs one ASV serves, in a scenario or a deployment. The papers' supervisory
#: controller serves three (Paper 2, Cases 6-8) and visits them in turn, so each AUV waits for
#: the others' visits: with ten a fix's age is already ten transits long. The MPC compiles one
#: problem per AUV count whose every stage holds each AUV's forecast and range bounds (about
#: 18 s to compile for one AUV, 28 s for three); a run's range figure has a panel per AUV.
#: 500 AUVs loaded, and the run did not finish writing in 5 minutes.
AUV_COUNT_MAX = 10
#: The fastest transit speed a controller may hand the execution level (m/s): about 20 knots,
#: three times the fastest shipped ASV (the Otter, 3.1 m/s). The execution level caps a speed
#: at the vessel's ``u_max`` (docs/vessel.md); 25 m/s was accepted and ran as 2.5.
TRANSIT_SPEED_MAX = 10.0
#: The longest Reference lead (m), a scenario's ``[sim] reference_lead_m`` and a deployment's
#: ``link.reference_lead_m``: a transit's waypoint pushed further than a kilometre is no
#: waypoint (``reference_lead_m = 1e9`` was accepted by a deployment)
REFERENCE_LEAD_MAX = 1000.0
#: A transit speed (m/s): in ``(0, TRANSIT_SPEED_MAX]``.
TransitSpeed = between(0, TRANSIT_SPEED_MAX, "m/s", "about 20 knots; the execution level caps "
                       "a speed at the vessel's u_max", lo_open=True)
#: The longest supervisory period (s): seconds, not hours (the papers' is 1 s). One bound for a
#: scenario's ``[sim] control_period`` and a deployment's ``controller.control_period``.
CONTROL_PERIOD_MAX = 60.0
#: A depth (m): in ``[0, DEPTH_MAX]``.
Depth = between(0, DEPTH_MAX, "m", "the deepest ocean is 10.9 km")
#: A horizontal coordinate, N or E (m): within ``DISTANCE_MAX`` of the origin.
Coord = between(-DISTANCE_MAX, DISTANCE_MAX, "m", "what the fastest AUV covers in a week")
#: A horizontal length or range (m): in ``(0, DISTANCE_MAX]``.
Length = between(0, DISTANCE_MAX, "m", "what the fastest AUV covers in a week", lo_open=True)
#: A time within a run (s): in ``[0, DURATION_MAX]``.
Time = between(0, DURATION_MAX, "s", "the longest run is a week")
#: A heading or angle (deg): ten turns either way at most (1e20 left the boat unable to turn:
#: a yaw step of 0.01 rad is lost in a float of that size).
Heading = between(-3600, 3600, "deg", "ten turns either way")
#: A boolean given as true or false, never as a string or a number ("yes", 1 and "off" were
#: taken as booleans).
Flag = Annotated[bool, Strict()]
#: A number >= 0.
NonNeg = Annotated[float, Strict(), Field(ge=0)]
#: A finite number >= 0 (``nan`` is "not a finite number", not "should be >= 0"; inf refused).
FiniteNonNeg = Annotated[float, Strict(), Field(ge=0, allow_inf_nan=False)]
#: A probability in [0, 1] (nan or inf: "not a finite number").
Prob = Annotated[float, Strict(), Field(ge=0, le=1, allow_inf_nan=False)]
#: A strictly positive integer.
PosInt = Annotated[int, Strict(), Field(gt=0)]
#: An integer >= 0.
NonNegInt = Annotated[int, Strict(), Field(ge=0)]
#: The largest seed: every seed is an integer in ``[0, SEED_MAX]`` (Optuna's samplers and the
#: results table's int64 column take no more; numpy would take any size)
SEED_MAX = 2**32 - 1
#: A seed (suites, scenarios' families): an integer in ``[0, SEED_MAX]``.
Seed = Annotated[int, Strict(), Field(ge=0, le=SEED_MAX)]


def _label(name: str) -> str:
    # control characters and line or paragraph separators only (isprintable() also refused a
    # no-break space and emoji joined with a zero-width joiner)
    control = any(unicodedata.category(c) in ("Cc", "Zl", "Zp") for c in name)
    if not name.strip() or name != name.strip() or control:
        raise ValueError(f"{name!r}: a name is one line, not empty, without leading or "
                         "trailing spaces")  # fmt: skip
    return name


#: A name shown in tables and messages (an AUV's): one line (no control character), not
#: empty, not padded.
Label = Annotated[str, Strict(), AfterValidator(_label)]


def check_path_name(name: str) -> str:
    """``name`` if it may be part of an output path (a :data:`PathName`).

    Raises
    ------
    ValueError
        Empty, padded, holding a control character, ``/`` or ``\\``, or starting with ``.``.
    """
    _label(name)
    if "/" in name or "\\" in name or name.startswith("."):
        raise ValueError(f"{name!r} is used in output paths: no / or \\, not starting with .")
    return name


#: A name used in output paths (``"../x"`` wrote outside the output folder, ``""`` named
#: nothing): a :data:`Label` without ``/`` or ``\\``, not starting with ``.``.
PathName = Annotated[str, Strict(), AfterValidator(check_path_name)]

STRICT = ConfigDict(extra="forbid", arbitrary_types_allowed=False)


def frozen(cls: type[T]) -> type[T]:
    """Decorate ``cls`` as a frozen dataclass validated by pydantic (unknown keys refused)."""
    return _pydantic_dataclass(frozen=True, config=STRICT)(cls)


class ConfigError(ValueError):
    """A configuration file (or mapping) is invalid; the message names the source and field."""


class FieldError(ValueError):
    """Raised by a model validator about one of its fields (a dotted path below the model,
    ``"limits.speed_max"``): :func:`parse` names that field where the model's own location
    alone (``auv[0]``, or ``(top level)``) would not say which one is wrong."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


#: the heading of :func:`parse`'s refusal (its problems follow, one per line)
INVALID = "invalid configuration"


def problems(exc: ConfigError) -> str:
    """``exc``'s problems in one line ("; "-joined), without :func:`parse`'s heading
    :data:`INVALID`: for a file refused inside another (a scenario's ``asv.vessel``; a
    falsification trial's scenario), which said "invalid configuration" twice."""
    lines = (ln.strip() for ln in str(exc).splitlines())
    return "; ".join(ln for ln in lines if ln and ln != INVALID)


def check_seed(seed: int, what: str = "--seed") -> int:
    """``seed`` if it is an integer in ``[0, SEED_MAX]``.

    Raises
    ------
    ConfigError
        Outside that range (``what`` names the option or field in the message).
    """
    if not 0 <= seed <= SEED_MAX:
        raise ConfigError(f"{what} {seed}: a seed is an integer in [0, 2**32 - 1]")
    return seed


def _format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def parse(cls: type[T], data: Mapping[str, Any], source: str | Path = "<mapping>") -> T:
    """Validate ``data`` into an instance of the frozen dataclass ``cls``.

    Raises
    ------
    ConfigError
        One line per problem: ``source: field.path: message``.
    """
    try:
        return TypeAdapter(cls).validate_python(dict(data))
    except ValidationError as exc:
        lines = [f"{source}: {_where(e)}: {_message(e)}" for e in exc.errors()]
        if len(lines) > MAX_PROBLEMS:  # an empty vessel file listed ~40 missing fields
            lines = [*lines[:MAX_PROBLEMS], f"... and {len(lines) - MAX_PROBLEMS} more"]
        raise ConfigError(f"{INVALID}\n  " + "\n  ".join(lines)) from None


#: the problems of one file listed at most (the rest counted)
MAX_PROBLEMS = 6


def _where(error: dict) -> str:
    """The field of one problem: pydantic's location, and below it the field a
    :class:`FieldError` names."""
    loc = tuple(error["loc"])
    cause = (error.get("ctx") or {}).get("error")
    if isinstance(cause, FieldError):
        loc += tuple(int(p) if p.isdigit() else p for p in cause.field.split("."))
    return _format_loc(loc)


def _message(error: dict) -> str:
    """Pydantic's message without its "Value error, " prefix (our validators' own words);
    nan or inf where a finite number belongs: "nan is not a finite number" (it read "Input
    should be greater than or equal to 0" for a nan depth)."""
    if error.get("type") == "finite_number":
        return f"{error.get('input')!r} is not a finite number"
    msg = str(error["msg"])
    return msg.removeprefix("Value error, ") if error.get("type") == "value_error" else msg


#: The kinds of mpcasv TOML file: the top-level keys every file of the kind has (and no other
#: kind has all of), and where such a file goes. A file of one kind given where another is
#: expected was refused with every field of the wrong kind, ~40 problems on one line.
KINDS: dict[str, tuple[frozenset[str], str]] = {
    "scenario": (frozenset({"asv", "auv"}), "mpcasv simulate SCENARIO"),
    "vessel": (frozenset({"m", "I_z", "X_u", "N_r"}), "--vessel"),
    "execution": (frozenset({"yaw", "speed", "reference"}), "--base, or asv.execution"),
    "suite": (frozenset({"scenarios", "controllers"}), "mpcasv compare SUITE"),
    "falsification family": (frozenset({"scenario", "param"}), "mpcasv falsify FAMILY"),
    "tuning range": (frozenset({"params", "objectives"}), "mpcasv tune controller RANGES"),
    "deploy": (frozenset({"identity", "link", "vehicle"}), "mpcasv deploy CONFIG"),
}


def kind_of(data: Mapping[str, Any]) -> str | None:
    """The kind of mpcasv file (a key of :data:`KINDS`) ``data`` (a TOML file's top-level
    table) is, or None if it has the keys of no kind."""
    return next((k for k, (keys, _) in KINDS.items() if keys <= data.keys()), None)


def check_kind(data: Mapping[str, Any], source: str | Path, expected: str) -> None:
    """Refuse a file of another kind (:func:`kind_of`) where a file of kind ``expected`` is
    read (e.g. a scenario given as ``--vessel``), in one line saying what it is and where it
    goes. A file of no known kind passes: its fields are checked by :func:`parse`.

    Raises
    ------
    ConfigError
        ``source: a scenario file (top-level asv, auv), not a vessel file; it goes to ...``.
    """
    found = kind_of(data)
    if found is None or found == expected:
        return
    keys, goes = KINDS[found]
    a, an = ("an" if k[0] in "aeiou" else "a" for k in (found, expected))
    raise ConfigError(f"{source}: {a} {found} file (top-level {', '.join(sorted(keys))}), not "
                      f"{an} {expected} file; {a} {found} file goes to {goes}")  # fmt: skip


def load_toml(path: str | Path, kind: str | None = None) -> dict[str, Any]:
    """Read a TOML file, turning I/O and syntax errors into :class:`ConfigError`; with
    ``kind`` (``"vessel"``, ``"scenario"``, ``"preset"``, ...), refuse a file of another kind
    (:func:`check_kind`)."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        if path.read_bytes().startswith(codecs.BOM_UTF8):  # TOML forbids it; editors add it
            raise ConfigError(f"{path}: not valid TOML: it starts with a UTF-8 byte-order mark "
                              "(BOM); save it as UTF-8 without one") from None  # fmt: skip
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    if kind is not None:
        check_kind(data, path, kind)
    return data


def load(cls: type[T], path: str | Path, kind: str | None = None) -> T:
    """Load and validate a TOML file into ``cls`` (``kind``: see :func:`load_toml`)."""
    return parse(cls, load_toml(path, kind), path)


def replace(obj: T, **changes: Any) -> T:
    """Return a re-validated copy of a frozen config dataclass with some fields changed."""
    data = dataclasses.asdict(obj)  # type: ignore[arg-type]
    data.update(changes)
    return parse(type(obj), data, f"{type(obj).__name__} override")


DATA_DIR = Path(__file__).parent / "data"


def is_path(name_or_path: str | Path) -> bool:
    """Whether a file reference is a path (ends in ``.toml`` or has a folder part) rather than
    the bare name of a shipped file such as ``"gretha"``."""
    s = str(name_or_path)
    return s.endswith(".toml") or "/" in s or "\\" in s


def anchor(name_or_path: str, base: str | Path) -> str:
    """A file reference made inside a configuration file, resolved against that file's folder.

    Paths (see :func:`is_path`) that are relative are joined to ``base`` (the folder of the file
    that names them) and returned absolute; absolute paths and bare shipped names are returned
    unchanged. So a scenario saying ``vessel = "otter.toml"`` means the ``otter.toml`` beside
    the scenario, whatever the working directory.
    """
    if not is_path(name_or_path):
        return name_or_path
    p = Path(name_or_path).expanduser()
    return str(p if p.is_absolute() else (Path(base) / p).resolve())


def resolve(kind: str, name_or_path: str | Path, base: str | Path | None = None) -> Path:
    """Find a shipped data file (``kind`` = ``vessels``, ``presets``, ...) or a user path.

    A bare name such as ``"gretha"`` means ``mpcasv/data/<kind>/gretha.toml``; a path (ending in
    ``.toml`` or with a folder part) is taken relative to ``base`` when given (the folder of the
    configuration file that names it, see :func:`anchor`), else as given (relative to the
    working directory).

    Raises
    ------
    ConfigError
        The path does not exist or is a file other than ``.toml``, or the name is not a
        shipped file (the shipped names listed).
    """
    if base is not None:
        name_or_path = anchor(str(name_or_path), base)
    p = Path(name_or_path)
    if p.suffix == ".toml" and p.exists():
        return p
    shipped = DATA_DIR / kind / f"{name_or_path}.toml"
    if not is_path(name_or_path) and shipped.exists():
        return shipped
    known = sorted(f.stem for f in (DATA_DIR / kind).glob("*.toml"))
    what = kind.removesuffix("s")  # the folder's name less a plural s ("execution" keeps its n)
    if p.is_file():  # it exists (a path or a bare name): it said "no such file" (s43)
        raise ConfigError(f"{str(name_or_path)!r}: not a {what} file (a {what} is a .toml file; "
                          f"shipped names: {known})")  # fmt: skip
    if is_path(name_or_path):
        raise ConfigError(f"unknown {what} {str(name_or_path)!r}: no such file (looked at "
                          f"{p.resolve()}; shipped names: {known})")  # fmt: skip
    raise ConfigError(
        f"unknown {what} {str(name_or_path)!r}: not a file, and not one of {known}"
    )
