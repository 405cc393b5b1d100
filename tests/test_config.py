"""The service configuration: the example file, its documentation, and one clear line per problem."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

from service.config import Config, ConfigError, documented_keys, load, parse

EXAMPLE = Path(__file__).resolve().parents[1] / "systemd" / "asrmap.toml"


def _write(tmp_path, text: str) -> Path:
    p = tmp_path / "asrmap.toml"
    p.write_text(text)
    return p


def test_the_example_file_is_the_defaults():
    cfg = load(EXAMPLE)
    assert cfg.robot == Config().robot and cfg.laser == Config().laser and cfg.zenoh == Config().zenoh
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:7447",) and cfg.zenoh.allow_commands == ()


def test_every_key_is_documented_in_the_example_file():
    data = tomllib.loads(EXAMPLE.read_text())
    present = {f"{s}.{k}" for s, t in data.items() for k in t}
    assert present == set(documented_keys())


def test_an_empty_file_gives_the_defaults(tmp_path):
    assert load(_write(tmp_path, "")).pioneer.port == "/dev/pioneer"


def test_ports_accept_serial_urls(tmp_path):
    cfg = load(_write(tmp_path, '[pioneer]\nport = "socket://10.0.0.2:8101"\n[laser]\nport = "rfc2217://h:7"\n'))
    assert cfg.pioneer.port == "socket://10.0.0.2:8101" and cfg.laser.port == "rfc2217://h:7"


@pytest.mark.parametrize(
    ("text", "key", "expected", "found"),
    [
        ("[laser]\nbaudrate = 12345\n", "laser.baudrate", "one of 9600, 19200, 38400, 500000", "12345"),
        ("[laser]\nresolution = 0.3\n", "laser.resolution", "one of 0.25, 0.5, 1.0", "0.3"),
        ('[laser]\nunits = "m"\n', "laser.units", 'one of "mm", "cm"', '"m"'),
        ('[pioneer]\nport = "ttyUSB0"\n', "pioneer.port", "a device path", '"ttyUSB0"'),
        ('[robot]\nname = "a/b"\n', "robot.name", "one Zenoh key chunk", '"a/b"'),
        ("[publish]\nscans = 1\n", "publish.scans", "true or false", "1"),
        ("[publish]\npose_rate = 0\n", "publish.pose_rate", "a number > 0", "0"),
        ('[zenoh]\nlisten = "tcp/127.0.0.1:7447"\n', "zenoh.listen", "a list of Zenoh endpoints", '"tcp/'),
        ('[zenoh]\nallow_commands = ["reboot"]\n', "zenoh.allow_commands", '"stop", "explore"', '["reboot"]'),
        ("[pipeline]\nscan_queue = 2.5\n", "pipeline.scan_queue", "an integer >= 1", "2.5"),
        ('[store]\npath = ""\n', "store.path", "naming a file, not a directory", '""'),
        ('[store]\npath = "maps/"\n', "store.path", "naming a file, not a directory", '"maps/"'),
        ("[laser]\nbaud = 38400\n", "laser.baud", "one of the keys port, baudrate", "an unknown key"),
        ("[lidar]\nport = 1\n", "lidar", "one of the sections", "an unknown section"),
        ("robot = 3\n", "robot", "a table [robot]", "3"),
    ],
)
def test_a_bad_value_is_one_line_naming_key_expected_and_found(tmp_path, text, key, expected, found):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load(path)
    lines = str(e.value).splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"{path}: {key}: expected ")
    assert expected in lines[0] and f"found {found}" in lines[0]


def test_several_problems_give_one_line_each(tmp_path):
    with pytest.raises(ConfigError) as e:
        load(_write(tmp_path, "[laser]\nbaudrate = 1\nfov = 90\n[robot]\nnom = 'x'\n"))
    assert [re.match(r".*?: (\S+):", line).group(1) for line in str(e.value).splitlines()] == [
        "laser.baudrate", "laser.fov", "robot.nom"]


def test_invalid_toml_is_one_line_with_its_position(tmp_path):
    with pytest.raises(ConfigError) as e:
        load(_write(tmp_path, "[laser\nport = 1\n"))
    msg = str(e.value)
    assert len(msg.splitlines()) == 1 and "not valid TOML" in msg and "line 1" in msg


def test_a_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load(tmp_path / "nope.toml")


def test_zenoh_config_is_relative_to_the_file_and_must_exist(tmp_path):
    (tmp_path / "z.json5").write_text("{mode: 'peer'}")
    cfg = load(_write(tmp_path, '[zenoh]\nconfig = "z.json5"\n'))
    assert cfg.zenoh.config == str((tmp_path / "z.json5").resolve())
    with pytest.raises(ConfigError, match=r"zenoh.config: expected an existing zenoh json5 file"):
        load(_write(tmp_path, '[zenoh]\nconfig = "missing.json5"\n'))


def test_zenoh_config_excludes_endpoints_in_the_toml(tmp_path):
    (tmp_path / "z.json5").write_text("{}")
    with pytest.raises(ConfigError, match=r"zenoh\.listen: expected no endpoints when zenoh\.config"):
        load(_write(tmp_path, '[zenoh]\nconfig = "z.json5"\nlisten = ["tcp/127.0.0.1:1"]\n'))


def test_mapper_overrides_are_validated_against_mapper_params():
    cfg = parse({"mapper": {"passage_width": 0.7}})
    assert cfg.mapper == (("passage_width", 0.7),) and cfg.mapper_params().passage_width == 0.7
    with pytest.raises(ConfigError) as e:
        parse({"mapper": {"pasage_width": 0.7, "laser_x": "near"}}, "f.toml")
    lines = str(e.value).splitlines()
    assert lines[0].startswith("f.toml: mapper.pasage_width: expected a MapperParams field (")
    assert lines[0].endswith("found an unknown key") and "passage_width" in lines[0]
    assert lines[1] == 'f.toml: mapper.laser_x: expected a number from -2 to 2; found "near"'


def test_mapper_numbers_lie_within_a_thousand_times_their_default_and_the_laser_within_2_m():
    """Beyond those ranges a value is a typing mistake, and some exhaust the robot's memory (a
    1e-9 m translation bin, a laser mounted 1e9 m away: MemoryError in the mapper thread)."""
    with pytest.raises(ConfigError) as e:
        parse({"mapper": {"passage_width": -0.6, "max_viewpoints": 0, "xy_bin": 1e-9, "angle_bin": 10.0,
                          "laser_x": 1e9}}, "f.toml")
    assert str(e.value).splitlines() == [
        "f.toml: mapper.passage_width: expected a number from 0.0006 to 600; found -0.6",
        "f.toml: mapper.max_viewpoints: expected an integer from 1 to 200000; found 0",
        "f.toml: mapper.xy_bin: expected a number from 0.005 to 0.5; found 1e-09",
        "f.toml: mapper.angle_bin: expected a number from 0.00174533 to 0.174533; found 10.0",
        "f.toml: mapper.laser_x: expected a number from -2 to 2; found 1000000000.0"]
    assert parse({"mapper": {"laser_x": -0.1, "laser_theta": -0.05}}).mapper_params().laser_x == -0.1


def test_cycle_closing_is_configured_in_a_mapper_cycles_table(tmp_path):
    p = tmp_path / "asrmap.toml"
    p.write_text("[mapper.cycles]\npaper = true\ncrosscheck_margin = 0.1\n")
    cycles = load(p).mapper_params().cycles
    assert not (cycles.verify or cycles.hindsight or cycles.realign) and cycles.crosscheck_margin == 0.1
    assert parse({}).mapper_params().cycles.verify  # the extensions are on by default
    with pytest.raises(ConfigError) as e:
        parse({"mapper": {"cycles": {"verfy": True, "search_radius": -1}}}, "f.toml")
    lines = str(e.value).splitlines()
    assert lines[0].startswith("f.toml: mapper.cycles.verfy: expected a CycleParams field (")
    assert lines[1] == "f.toml: mapper.cycles.search_radius: expected a number from 0 to 2000; found -1"
    with pytest.raises(ConfigError, match=r"mapper.cycles.loop_sigma_xy: expected a number from "
                                          r"0.0001 to 100; found 0\b"):
        parse({"mapper": {"cycles": {"loop_sigma_xy": 0}}}, "f.toml")  # divided by in the pose graph


def test_an_integer_is_accepted_for_a_float_parameter():
    assert parse({"mapper": {"passage_width": 1}}).mapper_params().passage_width == 1.0


def test_store_path_follows_state_directory(monkeypatch, tmp_path):
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    assert Config().store_path == tmp_path / "map.sqlite"
    assert parse({"store": {"state_dir": "/srv/x"}}).store_path == Path("/srv/x/map.sqlite")


def test_config_is_frozen():
    with pytest.raises(AttributeError):
        Config().robot.name = "other"
