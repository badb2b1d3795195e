"""Faults on the new surfaces (arm files, rigs, logged records, fitting options, the public
API): each input is refused with one line naming what is wrong, before any simulation."""

from pathlib import Path

import numpy as np
import pytest
from helpers import EXAMPLE

from jaxflex import Model, datasets, identify
from jaxflex.arm import ArmError, load_arm
from jaxflex.cli import main
from jaxflex.data import Record, load_record
from jaxflex.drives import VoltageDrive
from jaxflex.measured import model_record
from jaxflex.objective import build_objective
from jaxflex.rigs import arm_path
from jaxflex.sensors import DeflectionSensor, Encoder, StrainGauge
from jaxflex.testbed import Testbed as LinkSettings  # not collected as a test class

ROTFLEX = arm_path("quanser_rotflex")
TEXT = ROTFLEX.read_text(encoding="utf-8")


def _arm(tmp_path: Path, old: str, new: str) -> Path:
    """The packaged ROTFLEX arm file with ``old`` replaced by ``new`` (exactly once)."""
    assert TEXT.count(old) == 1, old
    path = tmp_path / "rig.toml"
    path.write_text(TEXT.replace(old, new), encoding="utf-8")
    return path


def _refused(path: Path, message: str) -> None:
    with pytest.raises(ArmError) as info:
        load_arm(path)
    assert str(info.value) == f"{path}: {message}"


# --- 1. encodings ---------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16", "utf-16-le-bom", "utf-16-be-bom"])
def test_an_arm_file_in_utf8_with_a_bom_or_utf16_with_a_bom_reads_as_in_utf8(tmp_path, encoding):
    text = TEXT.replace("Quanser SRV02 + ROTFLEX", "Quanser SRV02 + ROTFLEX (réglé)")
    if encoding.endswith("-bom"):
        codec = encoding.removesuffix("-bom")
        raw = ("\ufeff" + text).encode(codec)
    else:
        raw = text.encode(encoding)
    path = tmp_path / "rig.toml"
    path.write_bytes(raw)
    plain = tmp_path / "plain.toml"
    plain.write_text(text, encoding="utf-8")
    assert load_arm(path) == load_arm(plain)
    assert "réglé" in load_arm(path).description


def test_a_latin1_arm_file_is_refused_naming_the_file_the_line_and_the_byte(tmp_path):
    text = TEXT.replace("Quanser SRV02 + ROTFLEX", "Quanser SRV02 + ROTFLEX (réglé)")
    path = tmp_path / "rig.toml"
    path.write_bytes(text.encode("latin-1"))
    offset = text.index("é")  # the text before it is ASCII: one byte a character
    line = text[:offset].count("\n") + 1
    _refused(path, f"line {line}: byte {offset} (0xe9) is not UTF-8 (Latin-1 or Windows-1252?); "
                   "save the arm file as UTF-8")


def test_a_utf16_arm_file_without_a_byte_order_mark_is_refused_naming_the_encoding(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_bytes(TEXT.encode("utf-16-le"))
    _refused(path, "line 1: the file looks like UTF-16 without a byte-order mark; save it as UTF-8")


# --- 2. a misspelt sensor key ---------------------------------------------------------------


@pytest.mark.parametrize(("old", "new", "message"), [
    ("resolution = 6.4e-5", "resoluton = 6.4e-5",
     "sensors[1].resoluton: unknown key; did you mean 'resolution'?"),
    ('channel = "joint_angle"', 'chanel = "joint_angle"',
     "sensors[0].chanel: unknown key; did you mean 'channel'?"),
    ("counts_per_revolution = 4096", "counts_per_rev = 4096",
     "sensors[0].counts_per_rev: unknown key; did you mean 'counts_per_revolution'?"),
])
def test_a_misspelt_sensor_key_suggests_the_sensor_types_own_key(tmp_path, old, new, message):
    _refused(_arm(tmp_path, old, new), message)


def test_an_unknown_sensor_key_lists_every_key_of_that_sensor_type(tmp_path):
    _refused(_arm(tmp_path, "counts_per_revolution = 4096", "colour = 4096"),
             "sensors[0].colour: unknown key; known keys: ['channel', 'counts_per_revolution', "
             "'gain', 'noise', 'offset', 'reading_unit', 'resolution', 'rezero', 'type']")
    _refused(_arm(tmp_path, "x = 0.0 ", "colour = 0.0 "),
             "sensors[1].colour: unknown key; known keys: ['calibration', 'channel', 'gain', "
             "'noise', 'offset', 'reading_unit', 'resolution', 'rezero', 'type', 'x']")


def test_a_misspelt_optional_key_of_the_link_or_simulation_suggests_it(tmp_path):
    _refused(_arm(tmp_path, "n_substeps = 2", "n_substeps = 2\nn_mode = 4"),
             "simulation.n_mode: unknown key; did you mean 'n_modes'?")


# --- 3. and 8. the keys of sensor channels and n_modes ----------------------------------------


@pytest.mark.parametrize(("channel", "message"), [
    ("joint_angle", "sensors[1].channel: sensors[0] logs the channel 'joint_angle' too; each "
                    "sensor logs its own channel"),
    ("voltage", "sensors[1].channel: 'voltage' is the voltage drive's input, not a reading; name "
                "the sensor's own column"),
    ("time", "sensors[1].channel: 'time' is time, not a reading; name the sensor's own column"),
])
def test_a_sensor_channel_taken_by_another_sensor_the_input_or_time_names_its_key(
        tmp_path, channel, message):
    _refused(_arm(tmp_path, 'channel = "deflection_angle"', f'channel = "{channel}"'), message)


def test_a_default_channel_taken_twice_names_the_second_sensors_channel_key(tmp_path):
    path = _arm(tmp_path, "x = 0.0 ", "x = 0.0\n\n[[sensors]]\ntype = \"encoder\"\n")
    _refused(path, "sensors[2].channel: sensors[0] logs the channel 'joint_angle' too; each "
                   "sensor logs its own channel")


def test_too_many_modes_names_the_key(tmp_path):
    _refused(_arm(tmp_path, "n_substeps = 2", "n_substeps = 2\nn_modes = 1000"),
             "simulation.n_modes: expected a whole number in [1, 20], got 1000 (int)")


# --- 4. a degenerate link ---------------------------------------------------------------------


@pytest.mark.parametrize(("old", "new", "message"), [
    ("thickness = 0.0008128", "thickness = 1e-300",
     "link.thickness: 1e-300 m gives a bending stiffness E·I that is not a positive finite number "
     "(I = w·h³/12 = 0.0 m⁴)"),
    ("width = 0.02083", "width = 1e-320",
     "link.width: 1e-320 m gives a bending stiffness E·I that is not a positive finite number "
     "(I = w·h³/12 = 0.0 m⁴)"),
    ("density = 7850.0", "density = 1e-320",
     "link.density: 1e-320 kg/m³ gives a mass per length ρ·A = 0.0 kg/m that is not a positive "
     "finite number"),
    ("density = 7850.0", "density = 1e-310",  # a subnormal ρ·A: its precision lost
     "link.density: 1e-310 kg/m³ gives a mass per length ρ·A = 1.6930624e-315 kg/m that is not "
     "a positive finite number"),
    ("density = 7850.0", "mass = 1e-320",
     "link.mass: 1e-320 kg gives a mass per length ρ·A = "),
    ("length = 0.419", "length = 1e-120",
     "link.length: 1e-120 m gives an element stiffness E·I/l³ (l = 1e-121 m) that is not a "
     "positive finite number"),
])
def test_a_degenerate_link_is_refused_naming_the_key_and_why(tmp_path, old, new, message):
    path = _arm(tmp_path, old, new)
    with pytest.raises(ArmError) as info:
        load_arm(path)
    text = str(info.value)
    assert text.startswith(f"{path}: {message}") and "\n" not in text, text


def test_a_testbed_of_a_degenerate_link_is_refused_naming_the_setting():
    with pytest.raises(ValueError) as info:
        LinkSettings(thickness=1e-300)
    assert str(info.value) == (
        "testbed setting thickness=1e-300 gives a bending stiffness E·I that is not a positive "
        "finite number (I = w·h³/12 = 0.0 m⁴)")
    with pytest.raises(ValueError, match=r"^testbed setting clamp_offset=1e\+200 gives a link "
                                         r"inertia nan kg m² that is not a positive finite"):
        LinkSettings(clamp_offset=1e200)
    assert LinkSettings(thickness=1e-30).second_moment > 0  # thin, but a number: accepted


# --- 5. link readings in the wrong unit -------------------------------------------------------

RIG = load_arm("quanser_rotflex")


def _log(peak: float, channel: str = "deflection_angle") -> Record:
    """Half a second at rest, then a reading rising to ``peak`` (and the voltage, the angle)."""
    t = np.arange(0.0, 1.8, RIG.testbed.dt)
    rise = np.clip(t - 0.5, 0.0, 1.0)
    return Record(time=t, joint_angle=0.3 * rise,
                  extras={"voltage": np.where(t < 0.5, 0.0, 2.0), channel: peak * rise},
                  name="run1")


def test_a_deflection_angle_in_mrad_is_refused_naming_record_channel_peak_and_unit():
    model_record(RIG, _log(0.05))  # 50 mrad, in rad: accepted
    with pytest.raises(ValueError) as info:
        model_record(RIG, _log(50.0))
    assert str(info.value) == (
        "record 'run1': channel 'deflection_angle' reaches 50 rad from rest, a deflection angle "
        "above 1 rad; is it in mrad or degrees? a deflection angle must be in rad")


def test_a_tip_deflection_in_mm_is_refused():
    rig = RIG.replace(sensors=(Encoder(), DeflectionSensor(channel="laser", x=0.419)))
    model_record(rig, _log(0.03, "laser"))
    with pytest.raises(ValueError) as info:
        model_record(rig, _log(30.0, "laser"))
    assert str(info.value) == (
        "record 'run1': channel 'laser' reaches 30 m from rest, a deflection longer than the "
        "link (0.419 m); is it in mm (or mrad)? a deflection sensor's channel must be in m")


def test_a_strain_in_microstrain_is_refused_and_the_gain_counts():
    gauge = StrainGauge(channel="strain", x=0.05)
    rig = RIG.replace(sensors=(Encoder(), gauge))
    model_record(rig, _log(4e-4, "strain"))
    with pytest.raises(ValueError) as info:
        model_record(rig, _log(400.0, "strain"))
    assert str(info.value) == (
        "record 'run1': channel 'strain' reaches 400 m/m from rest, a strain above 1% (steel "
        "yields near 0.2 %); is it in µε or %? a strain channel must be in m/m")
    scaled = RIG.replace(sensors=(Encoder(), StrainGauge(channel="strain", x=0.05, gain=1e6)))
    model_record(scaled, _log(400.0, "strain"))  # a gauge calibrated in µε says so: accepted


# --- 6. --fix outside the rig's bounds --------------------------------------------------------


def test_a_fixed_value_outside_the_rigs_bounds_is_refused_by_the_api():
    record = load_record(EXAMPLE)
    message = ("fixed value beta=0.01 lies outside the rig's bounds [1e-07, 0.0002] s for beta; "
               "hold it within them, or widen them in the arm file")
    with pytest.raises(ValueError) as info:
        build_objective(record, fixed={"beta": 1e-2})
    assert str(info.value) == message
    with pytest.raises(ValueError) as info:
        identify(record, fixed={"beta": 1e-2}, generations=1)
    assert str(info.value) == message
    assert build_objective(record, fixed={"beta": 1e-4}).fixed["beta"] == 1e-4


def test_fix_outside_the_rigs_bounds_is_refused_naming_the_option(tmp_path, capsys):
    code = main(["identify", str(EXAMPLE), "--fix", "beta=1e-2", "--out",
                 str(tmp_path / "fit.json"), "--quiet"])
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and err == [
        "jaxflex identify: error: --fix beta=0.01 lies outside the rig's bounds [1e-07, 0.0002] "
        "s for beta; hold it within them, or widen them in the arm file"], err
    assert not (tmp_path / "fit.json").exists()


# --- 7. argument types of the public API ------------------------------------------------------


@pytest.mark.parametrize(("call", "error", "message"), [
    (lambda: load_arm(123), TypeError,
     "load_arm: path must be a file path or a packaged rig's name, got 123 (int)"),
    (lambda: identify(records=None), TypeError,
     "identify: records must be a Record, a Dataset or records, got None"),
    (lambda: identify(records="run1.csv"), TypeError,
     "identify: records must be a Record, a Dataset or records, got 'run1.csv' (str)"),
    (lambda: identify(records=[load_record(EXAMPLE), "run2.csv"]), TypeError,
     "identify: records[1] must be a Record, got 'run2.csv' (str)"),
    (lambda: datasets.load("quanser_rotflex", data_dir=123), TypeError,
     "datasets.load: data_dir must be a folder's path or None, got 123 (int)"),
    (lambda: Model(drive="voltage"), TypeError,
     "drive must be a drive (e.g. VoltageDrive(...)), got 'voltage' (str)"),
    (lambda: Model(sensors="x"), TypeError,
     "sensors must be a tuple of Sensors (e.g. (Encoder(),)), got 'x' (str)"),
    (lambda: Model(sensors=("x",)), TypeError,
     "sensors must be sensors (e.g. Encoder()), got 'x' (str)"),
    (lambda: Model(effects="payload"), TypeError,
     "effects must be a tuple of Effects (e.g. (Payload(),)), got 'payload' (str)"),
    (lambda: Model(testbed={"length": 0.4}), TypeError,
     "testbed must be a Testbed (e.g. Testbed(length=0.4)), got {'length': 0.4} (dict)"),
    (lambda: Model(fixed="J_h"), TypeError,
     "fixed must be a tuple of parameter names, got 'J_h'"),
])
def test_public_functions_name_the_argument_of_a_wrong_type(call, error, message):
    with pytest.raises(error) as info:
        call()
    assert str(info.value) == message


def test_a_model_of_the_right_types_is_built():
    model = Model(drive=VoltageDrive(resistance=2.6, torque_constant=7.68e-3,
                                     back_emf_constant=7.68e-3, gear_ratio=70.0,
                                     gearbox_efficiency=0.9, motor_efficiency=0.69),
                  sensors=[Encoder(channel="angle")], testbed=LinkSettings(length=0.4))
    assert model.sensors == (Encoder(channel="angle"),)
