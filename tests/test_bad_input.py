"""Bad input at the door: each case -> the exact line the user gets, exit code 2, no traceback.

Every case builds its bad input from a good one (a tiny studio recording rendered here, the
shared marker trials and BVH clips), runs the ``mocap-rt`` command in-process and checks the
last line of stderr word for word. The file-safety cases also check that nothing was lost
(the input or an earlier result is byte-identical afterwards). Two cases go through the real
``mocap-rt`` executable, as a user would.
"""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mocap_rt.cli import main

WALK = "bvh/cmu/cmu_02_01_walk.bvh"
TRC = "markers/opensim_models/gait2392_subject01_walk1.trc"
C3D = "markers/biobuddy_vicon_P01_lightweight/Test_func_lknee.c3d"
SEGMENTS = "mocap_rt/data/segments_biobuddy_vicon.toml"         # for the C3D
TRC_SEGMENTS = "mocap_rt/data/segments_opensim_gait.toml"       # for the TRC
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def good_rec(tmp_path_factory, data_dir) -> Path:
    """2 cameras, 160x120, 36 frames in two segments (30 + 6)."""
    from mocap_rt.studio.synth import make_rig, synthesize

    out = tmp_path_factory.mktemp("bad_input") / "rec"
    synthesize(data_dir / WALK, out, rig=make_rig(n_cameras=2, size=(160, 120)), seconds=1.2, truth_masks=False)
    return out


class Case:
    """``setup(tmp, rec, data) -> argv``; ``message`` with ``{tmp}`` / ``{rec}`` / ``{data}``;
    ``keep``: files (relative to tmp) that must be byte-identical after the command."""

    def __init__(self, name, setup, message, keep=()):
        self.name, self.setup, self.message, self.keep = name, setup, message, keep


def _copy(rec: Path, tmp: Path) -> Path:
    dst = tmp / "rec"
    shutil.copytree(rec, dst)
    return dst


def _edit(path: Path, old: str | re.Pattern, new: str) -> None:
    """``old`` (a string, or a pattern for values whose last digits are the writer's) -> ``new``, once."""
    text = path.read_text()
    if isinstance(old, re.Pattern):
        assert old.search(text), (path, old.pattern)
        path.write_text(old.sub(lambda _: new, text, count=1))
        return
    assert old in text, (path, old)
    path.write_text(text.replace(old, new, 1))


def _rec_with(toml_old: str, toml_new: str, cmd="process"):
    def setup(tmp, rec, data):
        r = _copy(rec, tmp)
        _edit(r / "recording.toml", toml_old, toml_new)
        return _cmd(cmd, r, tmp)
    return setup


def _cmd(cmd: str, r: Path, tmp: Path, *extra) -> list[str]:
    if cmd == "process":
        return ["process", str(r), "--out", str(tmp / "out"), "--no-progress", *extra]
    return ["run", "--source", f"replay:{r}", "--quiet", "--log-dir", str(tmp / "logs"), *extra]


def _frames_csv_without_rows(tmp, rec, data):
    r = _copy(rec, tmp)
    lines = (r / "frames.csv").read_text().splitlines(keepends=True)
    (r / "frames.csv").write_text("".join(lines[:11] + lines[21:]))        # frames 10..19 gone
    return _cmd("process", r, tmp)


def _frames_csv_tail_rows_missing(tmp, rec, data):
    r = _copy(rec, tmp)
    lines = (r / "frames.csv").read_text().splitlines(keepends=True)
    (r / "frames.csv").write_text("".join(lines[:-3]))                       # last 3 rows gone
    return _cmd("process", r, tmp)


def _rig_edit(old: str, new: str, cmd="process", own_rig=True):
    """Edit the recording's rig.toml (own_rig) or a copy passed with --rig (run)."""
    def setup(tmp, rec, data):
        r = _copy(rec, tmp)
        if own_rig:
            _edit(r / "rig.toml", old, new)
            return _cmd(cmd, r, tmp)
        rig = tmp / "other_rig.toml"
        rig.write_text((r / "rig.toml").read_text().replace(old, new))
        return _cmd(cmd, r, tmp, "--rig", str(rig))
    return setup


def _run_flags(*flags):
    return lambda tmp, rec, data: _cmd("run", _copy(rec, tmp), tmp, *flags)


def _truncated_truth(tmp, rec, data):
    r = _copy(rec, tmp)
    raw = (r / "truth.npz").read_bytes()
    (r / "truth.npz").write_bytes(raw[: len(raw) // 2])
    return _cmd("process", r, tmp, "--truth-2d")


def _bvh_with(value: str):
    def setup(tmp, rec, data):
        text = (data / WALK).read_text()
        head, motion = text.split("Frame Time:", 1)
        rows = motion.splitlines()
        parts = rows[3].split()
        parts[4] = value
        rows[3] = " ".join(parts)
        (tmp / "bad.bvh").write_text(head + "Frame Time:" + "\n".join(rows) + "\n")
        return ["synth", "--motion", str(tmp / "bad.bvh"), "--out", str(tmp / "synth"), "--seconds", "0.2",
                "--no-progress"]
    return setup


def _half_c3d(tmp, rec, data):
    raw = (data / C3D).read_bytes()
    (tmp / "half.c3d").write_bytes(raw[: len(raw) // 2])
    return ["joint-centres", str(tmp / "half.c3d"), "--segments", str(REPO / SEGMENTS), "--out", str(tmp / "o.trc")]


def _half_trc(tmp, rec, data):
    lines = (data / TRC).read_text().splitlines(keepends=True)
    (tmp / "half.trc").write_text("".join(lines[: 5 + (len(lines) - 5) // 2]))
    return ["joint-centres", str(tmp / "half.trc"), "--segments", str(REPO / TRC_SEGMENTS), "--out", str(tmp / "o.trc")]


def _trc_out_is_input(tmp, rec, data):
    shutil.copy(data / TRC, tmp / "T.trc")
    return ["joint-centres", str(tmp / "T.trc"), "--segments", str(REPO / TRC_SEGMENTS), "--out", str(tmp / "T.trc")]


def _trc_out_exists(tmp, rec, data):
    shutil.copy(data / TRC, tmp / "T.trc")
    (tmp / "earlier.trc").write_text("an earlier result\n")
    return ["joint-centres", str(tmp / "T.trc"), "--segments", str(REPO / TRC_SEGMENTS), "--out",
            str(tmp / "earlier.trc")]


def _earlier_process_output(*extra):
    def setup(tmp, rec, data):
        (tmp / "out").mkdir()
        (tmp / "out" / "bones.toml").write_text("[bones]\nthigh_m = 0.471\n")    # a subject's lengths
        (tmp / "c.toml").write_text('[fusion]\nfps = "x"\n')                       # a settings file
        return _cmd("process", rec, tmp, *(a.format(tmp=tmp) for a in extra))
    return setup


CASES = [
    # ---- recording.toml
    Case("fps-true", _rec_with("fps = 30.0", "fps = true"),
         "mocap-rt process: error: {tmp}/rec/recording.toml: field 'fps' must be a positive finite number, got true"),
    Case("fps-zero", _rec_with("fps = 30.0", "fps = 0"),
         "mocap-rt process: error: {tmp}/rec/recording.toml: field 'fps' must be a positive finite number, got 0"),
    Case("run-fps-nan", _rec_with("fps = 30.0", "fps = nan", cmd="run"),
         "mocap-rt run: error: {tmp}/rec/recording.toml: field 'fps' must be a positive finite number, got nan"),
    Case("run-segment-frames-negative", _rec_with("segment_frames = 30", "segment_frames = -30", cmd="run"),
         "mocap-rt run: error: {tmp}/rec/recording.toml: field 'segment_frames' must be an integer > 0, got -30"),
    Case("segment-frames-float", _rec_with("segment_frames = 30", "segment_frames = 2.5"),
         "mocap-rt process: error: {tmp}/rec/recording.toml: field 'segment_frames' missing or of the wrong type"),
    # ---- frames.csv
    Case("frames-csv-10-rows-missing", _frames_csv_without_rows,
         "mocap-rt process: error: {tmp}/rec/frames.csv, line 12: frame 20 follows 9 (10 rows missing): "
         "rows no longer match the video frames"),
    Case("frames-csv-last-rows-missing", _frames_csv_tail_rows_missing,
         "mocap-rt process: error: {tmp}/rec/frames.csv: 33 rows, but the video of 'cam_1' has 36 frames: "
         "rows are missing"),
    # ---- rigs
    Case("rig-fx-1e-300", _rig_edit("[ [ 138.5640646055102, 0.0, 79.5]", "[ [ 1e-300, 0.0, 79.5]"),
         "mocap-rt process: error: {tmp}/rec/rig.toml: [cam_1]: matrix fx = 1e-300 px is not "
         "a plausible focal length for an image 160 px wide (expected 1.6..16000 px)"),
    Case("rig-rotation-not-orthonormal",
         _rig_edit(re.compile(r"rotation = \[ 1\.8000282600718\d*, [^\]]*\]"),
                   "rotation = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0]]"),
         "mocap-rt process: error: {tmp}/rec/rig.toml: [cam_1]: camera 'cam_1': rotation is "
         "not a proper rotation matrix"),
    Case("rig-size-not-the-video", _rig_edit("size = [ 160.0, 120.0]", "size = [ 320.0, 240.0]"),
         "mocap-rt process: error: {tmp}/rec/video/cam_1/seg_000001.avi: images are 160x120, the rig's camera "
         "'cam_1' is 320x240 (rig.toml 'size')"),
    Case("run-rig-not-the-recording", _rig_edit('[cam_2]\nname = "cam_2"', '[cam_9]\nname = "cam_9"', "run", False),
         "mocap-rt run: error: --rig {tmp}/other_rig.toml: camera(s) ['cam_9'] are not in the recording {tmp}/rec "
         "(it has ['cam_1', 'cam_2'])"),
    Case("run-rig-wrong-image-size", _rig_edit("size = [ 160.0, 120.0]", "size = [ 320.0, 240.0]", "run", False),
         "mocap-rt run: error: --rig {tmp}/other_rig.toml: camera 'cam_1' has size 320x240, the recording's "
         "images are 160x120"),
    # ---- run options, before any node starts
    Case("run-bad-rerun-spec", _run_flags("--rerun", "save"),
         "mocap-rt run: error: --rerun 'save': expected save:FILE.rrd | serve[:WEB[:GRPC]] | spawn | connect:URL"),
    Case("run-bad-rerun-port", _run_flags("--rerun", "serve:http"),
         "mocap-rt run: error: --rerun 'serve:http': expected serve[:WEB_PORT[:GRPC_PORT]]"),
    Case("run-deadline-frac", _run_flags("--deadline-frac", "2"),
         "mocap-rt run: error: --deadline-frac must be in (0, 1], got 2.0"),
    Case("run-duration-nan", _run_flags("--duration", "nan"),
         "mocap-rt run: error: --duration must be a number > 0, got nan"),
    Case("run-preview-every-negative", _run_flags("--preview-every", "-3"),
         "mocap-rt run: error: --preview-every must be >= 0, got -3"),
    # ---- truth, BVH, markers
    Case("truth-npz-truncated", _truncated_truth,
         "mocap-rt process: error: {tmp}/rec/truth.npz: unreadable (BadZipFile: File is not a zip file); "
         "a truncated or damaged file?"),
    Case("bvh-nan", _bvh_with("nan"),
         "mocap-rt synth: error: {tmp}/bad.bvh: motion line 3 value 5 is nan: values must be finite and "
         "within +-1e+06"),
    Case("bvh-1e300", _bvh_with("1e300"),
         "mocap-rt synth: error: {tmp}/bad.bvh: motion line 3 value 5 is 1e+300: values must be finite and "
         "within +-1e+06"),
    Case("c3d-cut-in-half", _half_c3d,
         "mocap-rt joint-centres: error: {tmp}/half.c3d: the header declares 216 frames but 106 could be read "
         "(file cut?)"),
    Case("trc-half-its-rows", _half_trc,
         "mocap-rt joint-centres: error: {tmp}/half.trc: line 3: NumFrames=151 but the file has 75 data rows "
         "(cut or edited?)"),
    # ---- files never lost
    Case("joint-centres-out-is-input", _trc_out_is_input,
         "mocap-rt joint-centres: error: --out {tmp}/T.trc is the input {tmp}/T.trc; writing it would destroy "
         "the input (choose another output)", keep=("T.trc",)),
    Case("joint-centres-out-exists", _trc_out_exists,
         "mocap-rt joint-centres: error: --out: {tmp}/earlier.trc exists (an earlier run's result); pass "
         "--overwrite to replace it or choose another --out", keep=("earlier.trc",)),
    Case("process-second-run", _earlier_process_output(),
         "mocap-rt process: error: --out: {tmp}/out/bones.toml exists (an earlier run's result); pass "
         "--overwrite to replace it or choose another --out", keep=("out/bones.toml",)),
    Case("process-config-bad-value", _earlier_process_output("--config", "{tmp}/c.toml"),
         "mocap-rt process: error: {tmp}/c.toml [fusion]: fps = 'x' is not a number", keep=("out/bones.toml",)),
    Case("process-max-frames-0", _earlier_process_output("--max-frames", "0"),
         "mocap-rt process: error: --max-frames must be >= 1, got 0", keep=("out/bones.toml",)),
    # ---- parse errors
    Case("size-dashdash", lambda tmp, rec, data: ["calibrate", "dlt", "--points", "p.csv", "--size=--",
                                                  "--name", "c", "--out", str(tmp / "r.toml")],
         "mocap-rt: error: argument --size: expected a value, got '--'"),
]


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input_gets_one_clear_line(case, good_rec, data_dir, tmp_path, capsys):
    argv = case.setup(tmp_path, good_rec, data_dir)
    before = {k: (tmp_path / k).read_bytes() for k in case.keep}
    try:
        rc = main(argv)
    except SystemExit as exc:            # argparse's own errors
        rc = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert rc == 2, err
    want = case.message.format(tmp=tmp_path, rec=good_rec, data=data_dir)
    assert err.strip().splitlines()[-1] == want
    for k, b in before.items():
        assert (tmp_path / k).read_bytes() == b, f"{k} was changed"


@pytest.mark.parametrize("name", ["run-rig-not-the-recording", "joint-centres-out-is-input"])
def test_the_installed_command_prints_the_same_line(name, good_rec, data_dir, tmp_path):
    case = next(c for c in CASES if c.name == name)
    argv = case.setup(tmp_path, good_rec, data_dir)
    exe = Path(sys.executable).with_name("mocap-rt")
    p = subprocess.run([str(exe), *argv], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.strip().splitlines()[-1] == case.message.format(tmp=tmp_path, rec=good_rec, data=data_dir)
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").iterdir())   # no node was started


def test_run_record_says_when_it_writes_beside_an_earlier_recording(tmp_path):
    """The recorder never overwrites (it writes poses_001.*); the terminal says so before the run."""
    from nodes.cli import record_notice

    session = tmp_path / "session"
    assert record_notice(session) is None                    # a new directory
    session.mkdir()
    assert record_notice(session) is None                    # an empty one
    (session / "poses.bvh").write_text("earlier")
    assert record_notice(session) == (f"mocap-rt run: {session} already holds a recording; this one is written "
                                      f"as poses_001.bvh, poses_001.npz and bones_001.toml beside it")
