"""Every TOML file a user hands uvd — configuration, vehicle, parameters, log profile, campaign —
read through :func:`uvd.io.toml.read_toml`: a file that is not there, a folder, binary bytes
(not UTF-8) or broken TOML is one named error (the path and what is wrong), and on the command
line one line and exit 2, never a traceback. Before, a binary file ended in a UnicodeDecodeError
traceback from nine commands (``uvd check-config``, ``tune``, ``sim-bridge --config``,
``demo --config``, ``campaign``, ``xval --params``, ``identify --profile`` and ``--vehicle``,
``replay --realtime --config``), and a folder, a missing file or (``demo``) broken TOML in a
traceback from four."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from uvd.campaign.runs import kind_axes
from uvd.campaign.spec import CampaignError, load
from uvd.errors import ConfigError, ParameterError
from uvd.io.logprofile import load_profile
from uvd.io.params import linear_damping_from_toml, params_from_toml
from uvd.io.toml import TomlFileError, read_toml
from uvd.io.vehicle import load_vehicle
from uvd.links.mavlink.params import read_params_file
from uvd.runtime.config import ConfigValidationError, load_config

#: the start of a PNG file: a byte that is not UTF-8 (0x89) first
BINARY = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR"


def _bad_files(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name → (a .toml path, what its error must say)."""
    (tmp_path / "binary.toml").write_bytes(BINARY)
    (tmp_path / "folder.toml").mkdir()
    (tmp_path / "broken.toml").write_text("[vehicle\nname = 1\n")
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes('name = "Försök"\n'.encode("latin-1"))
    return {
        "binary": (tmp_path / "binary.toml",
                   "not a TOML file: not UTF-8 text (byte 0x89 at offset 0)"),
        "latin-1": (latin1, "not a TOML file: not UTF-8 text (byte 0xf6 at offset 9)"),
        "folder": (tmp_path / "folder.toml", "Is a directory"),
        "broken": (tmp_path / "broken.toml", "not valid TOML: "),
    }


def test_read_toml_names_the_file_and_what_is_wrong(tmp_path):
    for name, (path, says) in _bad_files(tmp_path).items():
        with pytest.raises(TomlFileError) as err:
            read_toml(path)
        assert str(err.value).startswith(f"{path}: "), name
        assert says in err.value.reason, (name, err.value.reason)
        assert isinstance(err.value, ConfigError)
    with pytest.raises(TomlFileError, match="cannot read the vehicle: No such file"):
        read_toml(tmp_path / "none.toml", "the vehicle")
    good = tmp_path / "good.toml"
    good.write_text('[a]\nb = "ü"\n', encoding="utf-8")
    assert read_toml(good) == {"a": {"b": "ü"}}


@pytest.mark.parametrize("reader, error", [
    (load_config, ConfigValidationError),
    (params_from_toml, ParameterError),
    (linear_damping_from_toml, ParameterError),
    (load_vehicle, ConfigError),
    (load_profile, ConfigError),
    (lambda p: load(p, kind_axes()), CampaignError),
    (read_params_file, ValueError),
])
def test_every_reader_of_a_users_toml_file_names_what_is_wrong(tmp_path, reader, error):
    for name, (path, says) in _bad_files(tmp_path).items():
        if name == "folder" and reader is load_profile:
            continue  # not a file: a profile is looked up by name (next test)
        with pytest.raises(error) as err:
            reader(path)
        assert str(path) in str(err.value) and says in str(err.value), (name, str(err.value))


def test_a_folder_for_a_log_profile_is_looked_up_as_a_name(tmp_path):
    (tmp_path / "folder.toml").mkdir()
    with pytest.raises(ConfigError, match="unknown log profile .*folder.toml.*not a file"):
        load_profile(tmp_path / "folder.toml")


def _uvd(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "uvd", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


def test_the_commands_say_it_in_one_line_and_exit_2(tmp_path):
    (tmp_path / "binary.toml").write_bytes(BINARY)
    (tmp_path / "folder.toml").mkdir()
    says = "binary.toml: not a TOML file: not UTF-8 text (byte 0x89 at offset 0)"
    for args in (["check-config", "binary.toml"], ["tune", "--config", "binary.toml"],
                 ["campaign", "binary.toml", "--out", "c"],
                 ["xval", "--params", "binary.toml", "--log", "none.mcap"],
                 ["demo", "--config", "binary.toml", "--duration", "1", "--record", "rec"]):
        r = _uvd(*args, cwd=tmp_path)
        assert r.returncode == 2 and says in r.stderr, (args, r.returncode, r.stderr)
        assert "Traceback" not in r.stderr, args
    r = _uvd("campaign", "folder.toml", "--out", "c", cwd=tmp_path)
    assert r.returncode == 2 and "folder.toml: cannot read the campaign file: Is a directory" \
        in r.stderr, r.stderr
    assert not (tmp_path / "c").exists() and not (tmp_path / "rec").exists()  # nothing started


def test_a_file_of_another_kind_is_named_for_what_it_is(tmp_path):
    # uvd's four kinds of TOML file handed to the wrong option used to fail on each of their
    # keys: a vehicle file to check-config "8 errors" of unknown keys, identify's own output
    # to --vehicle "unknown key(s) ['identified', 'refused']", a configuration to
    # xval --params "no [parameters] table"
    from uvd.io.vehicle import vehicle_path
    from uvd.shipped import config_path
    configuration = config_path("sim-bluerov2")
    vehicle = vehicle_path("jhu-rov")
    profile = vehicle.parents[1] / "logprofiles" / "ardusub-bin.toml"
    identified = tmp_path / "identified.toml"
    identified.write_text(vehicle.read_text().split("[thruster_defaults]")[0]
                          + "\n[identified]\nmethod = 'ls'\n\n[refused]\n")
    said = {"configuration": "this is a daemon configuration (uvd run --config, uvd "
                             "check-config), of vehicle 'bluerov2-heavy', not a",
            "vehicle": "this is a vehicle file (thrusters and the first guess: --vehicle, a "
                       "configuration's [vehicle] name), not a",
            "profile": "this is a log profile (--profile), not a",
            "parameters": "this is a parameter file (uvd identify --out; xval --params, "
                          "identify --init, [estimation] initial_params), not a"}
    campaign = profile.parents[1] / "campaign" / "builtin" / "smoke.toml"
    said["campaign"] = "this is a campaign file (uvd campaign FILE), not a"
    files = {"configuration": configuration, "vehicle": vehicle, "profile": profile,
             "parameters": identified, "campaign": campaign}
    readers = {"configuration": (load_config, ConfigValidationError, "daemon configuration"),
               "vehicle": (load_vehicle, ConfigError, "vehicle file"),
               "profile": (load_profile, ConfigError, "log profile"),
               "parameters": (params_from_toml, ParameterError, "parameter file"),
               "campaign": (lambda p: load(p, kind_axes()), CampaignError, "campaign file")}
    for wanted, (reader, error, name) in readers.items():
        for kind, path in files.items():
            if kind == wanted or (wanted == "parameters" and kind == "vehicle"):
                reader(path)  # its own kind reads; a vehicle file's [parameters] are one
                continue
            with pytest.raises(error) as err:
                reader(path)
            assert f"{path}: {said[kind]} {name}" in str(err.value), (wanted, str(err.value))
    # a file of the kind wanted, with a wrong key, is still told its key
    typo = tmp_path / "typo.toml"
    typo.write_text("colour = 1\n" + vehicle.read_text())
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['colour'\]"):
        load_vehicle(typo)
    r = _uvd("check-config", str(vehicle), cwd=tmp_path)
    assert r.returncode != 0 and r.stderr.count("\n") <= 3 and said["vehicle"] in r.stderr, \
        r.stderr
