"""``mocap-rt joint-centres`` end to end on a synthetic trial and on a shared real trial."""

import numpy as np
import pytest

from mocap_rt.cli import main
from mocap_rt.markers.io import read_c3d, read_trc, write_trc
from mocap_rt.markers.segments import dumps_segments, shipped_segments_path
from mocap_rt.markers.synthetic import simulate_body


def test_cli_on_synthetic_trial_writes_joint_markers_close_to_truth(tmp_path, capsys):
    data, segs, truth = simulate_body(n_frames=400, noise_m=0.001, gap_frac=0.01, seed=5)
    trial = tmp_path / "trial.trc"
    write_trc(trial, data)
    seg_path = tmp_path / "segments.toml"
    seg_path.write_text(dumps_segments(segs))
    out = tmp_path / "out" / "centres.trc"
    assert main(["joint-centres", str(trial), "--segments", str(seg_path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for name in truth:
        assert name in text
    assert "knee_r" in text and "±" in text
    res = read_trc(out)
    assert res.labels == tuple(truth)
    assert res.rate_hz == pytest.approx(data.rate_hz)
    for k, name in enumerate(res.labels):
        err = np.nanmean(np.linalg.norm(res.positions[:, k] - truth[name], axis=1))
        assert err < 0.02, (name, err)  # 1 mm marker noise, 6 cm marker stand-off


@pytest.mark.slow
@pytest.mark.parametrize("method", ["patent", "score", "sphere", "obrien"])
def test_cli_on_shared_vicon_hip_trial(data_dir, tmp_path, capsys, method):
    trial = data_dir / "markers/biobuddy_vicon_P01_lightweight/Test_func_rhip.c3d"
    out = tmp_path / "hip.trc"
    rc = main(["joint-centres", str(trial), "--segments", str(shipped_segments_path("biobuddy_vicon")),
               "--out", str(out), "--method", method])
    assert rc == 0
    text = capsys.readouterr().out
    assert f"hip_r        {method}" in text
    res = read_trc(out)
    hip = res.positions[:, res.labels.index("hip_r")]
    knee = res.positions[:, res.labels.index("knee_r")]
    thigh = np.linalg.norm(hip - knee, axis=1)
    # an adult thigh (hip to knee centre) is 0.35-0.55 m and rigid: the centre must not wander
    assert 0.35 < np.nanmean(thigh) < 0.55
    assert np.nanstd(thigh) < 0.005
    # the hip centre is below and lateral of mid-ASIS by a few cm (this file is -Z up)
    markers = read_c3d(trial)
    mid_asis = np.nanmean(markers.select(["LASI", "RASI"]), axis=1)
    offset = np.nanmean(np.linalg.norm(hip - mid_asis, axis=1))
    assert 0.05 < offset < 0.2


def test_cli_reports_unknown_markers_with_exit_2(data_dir, tmp_path, capsys):
    seg = tmp_path / "s.toml"
    seg.write_text('[segments.a]\nmarkers = ["LASI", "RASI", "NOPE"]\n'
                   '[segments.b]\nmarkers = ["RTHI", "RKNE", "RTHIB"]\n'
                   '[joints.j]\nparent = "a"\nchild = "b"\n')
    trial = data_dir / "markers/biobuddy_vicon_P01_lightweight/Test_func_rhip.c3d"
    rc = main(["joint-centres", str(trial), "--segments", str(seg), "--out", str(tmp_path / "o.trc")])
    assert rc == 2
    assert "NOPE" in capsys.readouterr().err
    assert not (tmp_path / "o.trc").exists()
