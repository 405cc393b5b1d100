"""The service configuration: a TOML file (``systemd/asrmap.toml`` documents every key) read into
frozen dataclasses.

Every problem is reported as a :class:`ConfigError` with one line per problem, each naming the key
by its dotted path, what was expected and what was found, e.g.
``/etc/asrmap/asrmap.toml: laser.baudrate: expected one of 9600, 19200, 38400, 500000; found 12345``.
Unknown keys are errors too: a misspelt key silently falling back to a default is how a robot
ends up driving with the wrong settings.

Units: seconds, hertz, metres, degrees where a key's name says so (``resolution_deg``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mapper.cycle_params import CycleParams
from mapper.cycle_params import limits as cycle_limits
from mapper.params import MapperParams
from mapper.params import limits as mapper_limits


class ConfigError(ValueError):
    """A configuration file that cannot be used; ``str()`` is one line per problem."""

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


# --- value checks: each returns the value (possibly normalised) or raises _Bad(expected) --------


class _Bad(Exception):
    def __init__(self, expected: str):
        self.expected = expected


def _str(v: Any) -> str:
    if not isinstance(v, str):
        raise _Bad("a string")
    return v


def _bool(v: Any) -> bool:
    if not isinstance(v, bool):
        raise _Bad("true or false")
    return v


def _number(lo: float, hi: float, *, integer: bool = False, lo_open: bool = False):
    what = "an integer" if integer else "a number"
    bounds = f"{'>' if lo_open else '>='} {lo:g}" + ("" if math.isinf(hi) else f" and <= {hi:g}")

    def check(v: Any):
        ok_type = isinstance(v, int) if integer else isinstance(v, int | float)
        if isinstance(v, bool) or not ok_type:
            raise _Bad(f"{what} {bounds}")
        if not math.isfinite(v) or v < lo or (lo_open and v == lo) or v > hi:
            raise _Bad(f"{what} {bounds}")
        return int(v) if integer else float(v)

    return check


def _one_of(*choices):
    def check(v: Any):
        for c in choices:
            # 1 and 1.0 are the same resolution, but true is not 1.
            if not isinstance(v, bool) and type(v) in (int, float, str) and v == c and type(c) is not bool:
                return c
        raise _Bad("one of " + ", ".join(_show(c) for c in choices))

    return check


_URL = re.compile(r"^[a-z][a-z0-9+.-]*://")


def _port(v: Any) -> str:
    """A serial device path (``/dev/pioneer``) or a pyserial URL (``socket://host:8101``)."""
    if not isinstance(v, str) or not (v.startswith("/") or _URL.match(v)):
        raise _Bad("a device path such as /dev/pioneer or a pyserial URL such as socket://10.0.0.2:8101")
    return v


_CHUNK = re.compile(r"^[A-Za-z0-9_.-]+$")
#: What a robot name must be, as the config and the command line say it.
ROBOT_NAME_EXPECTED = "a name of letters, digits, '_', '-' or '.' (one Zenoh key chunk)"


def is_robot_name(v: Any) -> bool:
    """One Zenoh key chunk: no '/', no wildcards, not '@'-prefixed (a robot name in the key space)."""
    return isinstance(v, str) and bool(_CHUNK.match(v))


def _key_chunk(v: Any) -> str:
    if not is_robot_name(v):
        raise _Bad(ROBOT_NAME_EXPECTED)
    return v


_ENDPOINT = re.compile(r"^[a-z0-9-]+/\S+$")


def _endpoints(v: Any) -> tuple[str, ...]:
    expected = 'a list of Zenoh endpoints such as ["tcp/127.0.0.1:7447"]'
    if not isinstance(v, list) or not all(isinstance(e, str) and _ENDPOINT.match(e) for e in v):
        raise _Bad(expected)
    return tuple(v)


COMMANDS = ("stop", "explore")


def _commands(v: Any) -> tuple[str, ...]:
    if not isinstance(v, list) or not all(c in COMMANDS for c in v):
        raise _Bad("a list of command names from " + ", ".join(f'"{c}"' for c in COMMANDS))
    return tuple(v)


def _path(v: Any) -> str:
    if not isinstance(v, str):
        raise _Bad("a file path (string)")
    return v


def _file_name(v: Any) -> str:
    if not isinstance(v, str) or not v.strip() or v.endswith(("/", "\\")) or v.strip() in (".", ".."):
        raise _Bad("a file path (a non-empty string naming a file, not a directory)")
    return v


def _show(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list):
        s = "[" + ", ".join(_show(i) for i in v) + "]"
        return s if len(s) < 60 else s[:57] + "...]"
    return repr(v)


def _key(check, doc: str, **kw):
    """A dataclass field carrying its value check and its one-line documentation."""
    return field(metadata={"check": check, "doc": doc}, **kw)


# --- the sections ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class RobotConfig:
    name: str = _key(_key_chunk, "robot name: the Zenoh key prefix is asrmap/<name>/", default="pioneer")


#: bit/s: the host-port rates P2OS offers (HOSTBAUD 0-4) and the LMS2xx's serial rates.
PIONEER_BAUDS = (9600, 19200, 38400, 57600, 115200)
LASER_BAUDS = (9600, 19200, 38400, 500000)


@dataclass(frozen=True)
class PioneerConfig:
    port: str = _key(_port, "serial device or pyserial URL of the Pioneer", default="/dev/pioneer")
    baudrate: int = _key(_one_of(*PIONEER_BAUDS), "P2OS baud rate (bit/s)", default=9600)
    model: str = _key(_one_of("p2dx"), "robot model (wheel geometry, SIP scaling)", default="p2dx")


@dataclass(frozen=True)
class LaserConfig:
    port: str = _key(_port, "serial device or pyserial URL of the SICK LMS2xx", default="/dev/sick")
    baudrate: int = _key(_one_of(*LASER_BAUDS), "LMS2xx baud rate (bit/s)", default=38400)
    resolution: float = _key(_one_of(0.25, 0.5, 1.0), "angular resolution (degrees)", default=1.0)
    fov: int = _key(_one_of(100, 180), "field of view (degrees)", default=180)
    units: str = _key(_one_of("mm", "cm"), "range units the scanner reports (mm: 8 m max, cm: 80 m max)",
                      default="mm")


@dataclass(frozen=True)
class ZenohConfig:
    listen: tuple[str, ...] = _key(_endpoints, "endpoints the service listens on (loopback by default)",
                                   default=("tcp/127.0.0.1:7447",))
    connect: tuple[str, ...] = _key(_endpoints, "endpoints (routers, peers) the service connects to",
                                    default=())
    config: str = _key(_path, "a zenoh json5 configuration that replaces the default session", default="")
    allow_commands: tuple[str, ...] = _key(_commands, "cmd/* queryables that are obeyed; others are refused",
                                           default=())


@dataclass(frozen=True)
class StoreConfig:
    state_dir: str = _key(_path, "state directory ($STATE_DIRECTORY when empty, else /var/lib/asrmap)",
                          default="")
    path: str = _key(_file_name, "SQLite map store, relative to state_dir", default="map.sqlite")


@dataclass(frozen=True)
class PublishConfig:
    scans: bool = _key(_bool, "publish every scan on asrmap/<robot>/scan (binary)", default=False)
    pose_rate: float = _key(_number(0.0, 100.0, lo_open=True), "pose publication rate (Hz)", default=10.0)
    status_rate: float = _key(_number(0.0, 10.0, lo_open=True), "status publication rate (Hz)", default=1.0)


@dataclass(frozen=True)
class PipelineConfig:
    scan_queue: int = _key(_number(1, 10000, integer=True),
                           "scans waiting for the mapper; the oldest is dropped when full", default=8)
    odometry_history: float = _key(_number(0.5, 60.0), "odometry kept for interpolation (s)", default=5.0)


@dataclass(frozen=True)
class WatchdogConfig:
    scan_timeout: float = _key(_number(0.05, 60.0), "no scan for this long: the laser is faulty (s); "
                               "the robot is stopped while it is blind", default=0.5)
    odometry_timeout: float = _key(_number(0.05, 60.0), "no SIP for this long: the Pioneer is faulty (s)",
                                   default=0.5)
    reconnect_interval: float = _key(_number(0.05, 60.0), "pause between reconnection attempts (s)",
                                     default=1.0)
    startup_timeout: float = _key(_number(0.0, 3600.0), "the Pioneer and the laser not both up this long "
                                  "after start: exit with status 1 naming what is missing, so systemd "
                                  "restarts the service (s; 0 waits for ever; keep below TimeoutStartSec)",
                                  default=90.0)
    mapper_stall: float = _key(_number(1.0, 3600.0), "the mapper busy on one reading this long stops the "
                               "systemd watchdog pings, so systemd restarts the service (s)", default=30.0)


@dataclass(frozen=True)
class Config:
    """The whole service configuration; ``mapper`` holds MapperParams overrides by field name."""

    robot: RobotConfig = field(default_factory=RobotConfig)
    pioneer: PioneerConfig = field(default_factory=PioneerConfig)
    laser: LaserConfig = field(default_factory=LaserConfig)
    mapper: tuple[tuple[str, Any], ...] = ()
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)
    store: StoreConfig = field(default_factory=StoreConfig)
    publish: PublishConfig = field(default_factory=PublishConfig)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    watchdog: WatchdogConfig = field(default_factory=WatchdogConfig)
    source: str = ""

    @property
    def store_path(self) -> Path:
        """The SQLite file of the map store (absolute)."""
        env = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
        base = self.store.state_dir or env or "/var/lib/asrmap"
        return Path(base) / self.store.path

    def mapper_params(self):
        """``MapperParams`` with the ``[mapper]`` overrides applied."""
        overrides = dict(self.mapper)
        if "cycles" in overrides:
            cycles = dict(overrides["cycles"])
            base = CycleParams.paper() if cycles.pop("paper", False) else CycleParams()
            overrides["cycles"] = base.replace(**cycles)
        return MapperParams(**overrides)


_SECTION_TYPES = {
    "robot": RobotConfig, "pioneer": PioneerConfig, "laser": LaserConfig, "zenoh": ZenohConfig,
    "store": StoreConfig, "publish": PublishConfig, "pipeline": PipelineConfig, "watchdog": WatchdogConfig,
}


def _defaults(cls: type) -> dict[str, Any]:
    """A parameters dataclass's field defaults by name."""
    return {f.name: getattr(cls(), f.name) for f in dataclasses.fields(cls)}


def _check_fields(prefix: str, table: dict, known: dict[str, Any], what: str, problems: list[str],
                  limits: Callable[[str], tuple[float, float]] | None = None) -> list[tuple[str, Any]]:
    """Overrides of a parameters dataclass (``known``: its defaults by field name), each checked
    against its default's type; numbers must lie within ``limits(name)`` (closed)."""
    out = []
    for name, v in table.items():
        if name not in known:
            problems.append(f"{prefix}.{name}: expected a {what} field ({', '.join(sorted(known))}); "
                            f"found an unknown key")
            continue
        default = known[name]
        if isinstance(default, bool):
            ok, expected = isinstance(v, bool), "true or false"
        elif isinstance(default, int | float):
            ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            if isinstance(default, int) and not isinstance(v, int):
                ok = False
            expected = "an integer" if isinstance(default, int) else "a number"
            if limits is not None:
                lo, hi = limits(name)
                ok = ok and lo <= v <= hi
                expected += f" from {lo:g} to {hi:g}"
            v = float(v) if ok and isinstance(default, float) else v
        elif isinstance(default, str):
            ok, expected = isinstance(v, str), "a string"
        else:
            ok, expected = not isinstance(v, dict), "a value"
        if not ok:
            problems.append(f"{prefix}.{name}: expected {expected}; found {_show(v)}")
        else:
            out.append((name, v))
    return out


def _check_mapper(table: dict, problems: list[str]) -> tuple[tuple[str, Any], ...]:
    cycles = table.get("cycles")
    rest = {k: v for k, v in table.items() if k != "cycles"}
    out = _check_fields("mapper", rest, _defaults(MapperParams), "MapperParams", problems,
                        limits=mapper_limits)
    if cycles is not None:
        if not isinstance(cycles, dict):
            problems.append(f"mapper.cycles: expected a table [mapper.cycles] of CycleParams fields; "
                            f"found {_show(cycles)}")
        else:
            fields = _defaults(CycleParams)
            fields["paper"] = False  # start from CycleParams.paper(): the paper's method alone
            # 0 is meaningful for most (a margin or a search radius of 0 is the paper's test)
            out.append(("cycles", tuple(_check_fields("mapper.cycles", cycles, fields, "CycleParams",
                                                      problems, limits=cycle_limits))))
    return tuple(out)


def _section(name: str, cls: type, table: Any, problems: list[str]):
    if not isinstance(table, dict):
        problems.append(f"{name}: expected a table [{name}]; found {_show(table)}")
        return cls()
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for key, v in table.items():
        f = fields.get(key)
        if f is None:
            keys = ", ".join(fields)
            problems.append(f"{name}.{key}: expected one of the keys {keys}; found an unknown key")
            continue
        try:
            values[key] = f.metadata["check"](v)
        except _Bad as bad:
            problems.append(f"{name}.{key}: expected {bad.expected}; found {_show(v)}")
    return cls(**values)


def parse(data: dict[str, Any], source: str = "<config>") -> Config:
    """Validate an already parsed TOML document; ``source`` prefixes each problem line."""
    problems: list[str] = []
    sections: dict[str, Any] = {}
    mapper: tuple[tuple[str, Any], ...] = ()
    for name, table in data.items():
        if name == "mapper":
            if isinstance(table, dict):
                mapper = _check_mapper(table, problems)
            else:
                problems.append(f"mapper: expected a table [mapper]; found {_show(table)}")
        elif name in _SECTION_TYPES:
            sections[name] = _section(name, _SECTION_TYPES[name], table, problems)
        else:
            problems.append(f"{name}: expected one of the sections {', '.join(['mapper', *_SECTION_TYPES])}; "
                            f"found an unknown section")
    z = data.get("zenoh")
    if isinstance(z, dict) and z.get("config"):
        for k in ("listen", "connect"):
            if k in z:
                problems.append(f"zenoh.{k}: expected no endpoints when zenoh.config names a file (put them "
                                f"in that file); found {_show(z[k])}")
    if problems:
        raise ConfigError([f"{source}: {p}" for p in problems])
    return Config(mapper=mapper, source=source, **sections)


def load(path: str | os.PathLike) -> Config:
    """Read and validate a config file. A relative ``zenoh.config`` is taken relative to the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError([f"{path}: config file not found (check the path given to --config)"]) from None
    except OSError as exc:
        raise ConfigError([f"{path}: cannot read the config file: {exc.strerror}"]) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([f"{path}: not valid TOML: {exc}"]) from None
    cfg = parse(data, str(path))
    if cfg.zenoh.config:
        zpath = path.parent / cfg.zenoh.config
        if not zpath.is_file():
            raise ConfigError([f"{path}: zenoh.config: expected an existing zenoh json5 file; found "
                               f"{_show(cfg.zenoh.config)} ({zpath} does not exist)"])
        cfg = dataclasses.replace(cfg, zenoh=dataclasses.replace(cfg.zenoh, config=str(zpath.resolve())))
    return cfg


def documented_keys() -> dict[str, str]:
    """Every key as ``section.key`` with its one-line documentation (the example file mirrors this)."""
    out = {}
    for name, cls in _SECTION_TYPES.items():
        for f in dataclasses.fields(cls):
            out[f"{name}.{f.name}"] = f.metadata["doc"]
    return out
