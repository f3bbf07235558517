"""Units of the states and actions: from JointState fields, derived actions and the config's
``units``, shown in run.json and report.md."""

import json

import pytest
from writers import JOINTS, joint_recording, write_csv, write_mcap_ros2

from ccl_cli.cli import main
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io import read_dataset


def test_joint_state_fields_are_in_radians():
    from ccl_cli.io.units import field_unit

    assert [field_unit(f"{JOINTS[0]}.{f}") for f in ("position", "velocity", "effort", "other")] == \
        ["rad", "rad/s", "N m", ""]


def test_units_from_a_bag_and_derived_actions(tmp_path):
    path = write_mcap_ros2(tmp_path / "r.mcap", joint_recording(n=200))
    data, _ = read_dataset({"state": {"topic": "/joint_states", "field": "position"},
                            "action": {"derive": "state"}}, [path])
    assert data.state_units == ["rad"] * 7 and data.action_units == ["rad/s"] * 7
    data, _ = read_dataset({"state": {"topic": "/joint_states", "field": "position"},
                            "action": {"topic": "/joint_states", "field": "velocity"}}, [path])
    assert data.state_names == [f"{j}.position" for j in JOINTS]  # named from the messages
    assert data.action_units == ["rad/s"] * 7
    with pytest.raises(InputError, match=r"field 'effort' of /joint_states is empty"):
        read_dataset({"state": {"topic": "/joint_states", "field": "position"},
                      "action": {"topic": "/joint_states", "field": "effort"}}, [path])


def test_configured_units_and_their_count(tmp_path):
    path = write_csv(tmp_path / "r.csv", joint_recording(n=200), duplicate_names=False)
    options = {"state": {"columns": ["px", "py", "pz"], "units": "m"}, "action": {"derive": "state"}}
    data, _ = read_dataset(options, [path])
    assert data.state_units == ["m"] * 3 and data.action_units == ["m/s"] * 3
    options["state"]["units"] = ["m", "m", "deg"]
    data, _ = read_dataset(options, [path])
    assert data.state_units == ["m", "m", "deg"] and data.action_units == ["m/s", "m/s", "deg/s"]
    options["state"]["units"] = ["m", "m"]
    with pytest.raises(ConfigError, match=r"data.state.units lists 2 units for 3 dimensions"):
        read_dataset(options, [path])


@pytest.fixture
def joint_log(tmp_path):
    """An MCAP JointState log and a config that names no joints: (recording, config)."""
    path = write_mcap_ros2(tmp_path / "r.mcap", joint_recording(n=400))
    config = tmp_path / "c.yaml"
    config.write_text(json.dumps({"data": {"state": {"topic": "/joint_states", "field": "position"},
                                           "action": {"topic": "/joint_states", "field": "velocity"}},
                                  "learn-a": {"method": "nhat"}, "stages": ["learn-a"]}))
    return path, config


def test_report_and_run_record_name_the_units(capsys, tmp_path, joint_log):
    path, config = joint_log
    code = main(["run", str(config), "--data", str(path), "-o", str(tmp_path / "out"), "-q"])
    err = capsys.readouterr().err
    assert code == 0, err
    record = json.loads((tmp_path / "out" / "run.json").read_text())
    assert record["data"]["states"][0] == f"{JOINTS[0]}.position [rad]"
    assert record["data"]["actions"][0] == f"{JOINTS[0]}.velocity [rad/s]"
    assert f"{JOINTS[0]}.velocity [rad/s]" in (tmp_path / "out" / "report.md").read_text()


def test_predictions_name_each_column_with_its_unit(tmp_path, joint_log):
    path, config = joint_log
    assert main(["learn-a", str(path), "-c", str(config), "-o", str(tmp_path / "a"), "-q"]) == 0
    assert main(["predict", str(tmp_path / "a" / "model.h5"), str(path), "-c", str(config),
                 "-o", str(tmp_path / "p.csv"), "-q"]) == 0
    header = (tmp_path / "p.csv").read_text().splitlines()[0].split(",")
    assert header[0] == f"x.{JOINTS[0]}.position [rad]"
    assert f"w.{JOINTS[6]}.velocity [rad/s]" in header and "t [s]" in header and "demo" in header
