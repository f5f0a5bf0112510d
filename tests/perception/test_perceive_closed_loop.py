"""``mocap-rt perceive`` closes the loop through fusion by default (issue 12 item 2).

Truth: the studio's rendered 2D cues. The closed loop is the one ``mocap-rt process``
runs (``fusion.offline.run_tracker``); ``--open-loop`` is each camera on its own tracks.
"""

import numpy as np
import pytest

from mocap_rt.names import CUE_NAMES


@pytest.fixture(scope="module")
def dance_recording(data_dir, tmp_path_factory):
    from mocap_rt.studio.synth import make_rig, synthesize

    out = tmp_path_factory.mktemp("perceive") / "dance"
    synthesize(data_dir / "bvh" / "cmu" / "cmu_05_06_modern_dance.bvh", out, rig=make_rig(size=(320, 240)),
               seconds=0.5, start_s=1.0, truth_masks=False)
    return out


def _errors(z, truth):
    """(C, F, 5) 2D error of head, hands, feet where the truth sees the cue (NaN elsewhere)."""
    t2d = truth["cues_2d"][:, : z["cues_2d"].shape[1], :5]
    vis = truth["cue_visibility"][:, : z["cues_2d"].shape[1], :5] >= 0.5
    err = np.hypot(*(z["cues_2d"][..., :5, :] - t2d).transpose(3, 0, 1, 2))
    return np.where(vis, err, np.nan)


@pytest.mark.slow
def test_perceive_closed_loop_by_default_and_open_loop_on_request(dance_recording, tmp_path):
    from mocap_rt.cli import main
    from mocap_rt.io.recording import Recording

    truth = Recording(dance_recording).truth
    assert main(["perceive", str(dance_recording), "--out", str(tmp_path / "closed.npz"), "--no-progress"]) == 0
    assert main(["perceive", str(dance_recording), "--out", str(tmp_path / "open.npz"), "--no-progress",
                 "--open-loop"]) == 0
    closed, opened = np.load(tmp_path / "closed.npz"), np.load(tmp_path / "open.npz")
    assert closed["closed_loop"] and not opened["closed_loop"]
    assert list(closed["cue_names"]) == list(CUE_NAMES)
    e_closed = _errors(closed, truth)
    # frame 0 has no prediction yet: both loops see the same first frame
    np.testing.assert_array_equal(closed["cues_2d"][:, 0], opened["cues_2d"][:, 0])
    # from the second frame on fusion's predictions guide the closed loop, which changes the cues
    assert not np.array_equal(np.nan_to_num(closed["cues_2d"][:, 1:]), np.nan_to_num(opened["cues_2d"][:, 1:]))
    assert np.isfinite(e_closed).mean() > 0.85 * np.isfinite(_errors(opened, truth)).mean()
    assert np.nanmedian(e_closed) < 1.5                       # px at 320x240
    assert np.nanpercentile(e_closed, 90) < 5.0
