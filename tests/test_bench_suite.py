"""The motion suite's clip names (bench/suite.py): fresh held-out clips named on the command line."""

import pytest

from bench.suite import SEGMENT_S, select, suite_clips


def test_a_shared_recording_at_another_start_is_a_held_out_window(data_dir):
    (walk, jumps) = select(suite_clips("default"), "cmu_02_01_walk@0.5,cmu_01_01_playground_forward_jumps@14")
    assert (walk.motion, walk.start_s, walk.seconds, walk.kind) == ("cmu/cmu_02_01_walk.bvh", 0.5, SEGMENT_S, "held-out")
    assert jumps.start_s == 14.0 and jumps.variant is None


@pytest.mark.parametrize("name", ["cmu_02_01_walk@", "cmu_02_01_walk@soon", "cmu_02_01_walk@-1", "no_such_clip@2"])
def test_a_window_that_names_no_recording_or_start_is_refused(data_dir, name):
    with pytest.raises(SystemExit, match="unknown suite clip"):
        select(suite_clips("default"), name)


def test_a_window_past_the_recordings_end_is_refused_before_rendering(data_dir, tmp_path, monkeypatch):
    import bench.suite as suite

    monkeypatch.setattr(suite, "CACHE", tmp_path)
    (late,) = select(suite_clips("default"), "cmu_02_01_walk@9")
    with pytest.raises(SystemExit, match=r"cmu_02_01_walk@9: starts at 9 s, but cmu/cmu_02_01_walk.bvh is 2.8 s long"):
        suite.ensure_recording(late)
    assert not any(p.is_dir() for p in tmp_path.iterdir())      # nothing rendered
