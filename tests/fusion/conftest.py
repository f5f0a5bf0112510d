"""Short studio recordings of a backwards walk, rendered once per session (identity tests)."""

import pytest

BACKWARDS_WALK_FRAMES = 45


def _backwards_walk(tmp_path_factory, data_dir, frames: int):
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    bvh, name = load_motion(data_dir / "bvh" / "cmu" / "cmu_131_01_start_walk_stop.bvh", "reversed")
    out = tmp_path_factory.mktemp("backwards_walk") / "rec"
    synthesize(bvh, out, rig=make_rig("ring", size=(320, 240)), fps=30.0, seconds=frames / 30.0,
               start_s=2.0, seed=3, motion_name=name)
    return out


@pytest.fixture(scope="session")
def backwards_walk(tmp_path_factory, data_dir):
    """cmu_131_01 played backwards (walking backwards), 1.5 s from 2.0 s, 6-camera ring at
    320x240, 30 fps, with truth and silhouettes: the recording directory."""
    return _backwards_walk(tmp_path_factory, data_dir, BACKWARDS_WALK_FRAMES)


@pytest.fixture(scope="session")
def backwards_walk_3s(tmp_path_factory, data_dir):
    """The same walk for 3 s (a feet swap made mid-clip is put right by its 46th frame)."""
    return _backwards_walk(tmp_path_factory, data_dir, 2 * BACKWARDS_WALK_FRAMES)


@pytest.fixture(scope="session")
def kick_reversed(tmp_path_factory, data_dir):
    """The Bandai kick played backwards, its first 0.5 s (standing, feet 0.7 m apart, hands
    0.65 m apart), 6-camera ring at 320x240, 30 fps, with truth and silhouettes."""
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    bvh, name = load_motion(data_dir / "bvh" / "bandai_namco" / "dataset-1_kick_normal_001.bvh", "reversed")
    out = tmp_path_factory.mktemp("kick_reversed") / "rec"
    synthesize(bvh, out, rig=make_rig("ring", size=(320, 240)), fps=30.0, seconds=0.5, start_s=0.0, seed=3,
               motion_name=name)
    return out


@pytest.fixture(scope="session")
def turn_in_place(tmp_path_factory):
    """The procedural turn on the spot (seed 0), 2.5 s from 0.8 s as the suite plays it: the feet
    step apart and together, touching at frames 36-40 and 62-68 and standing 20-25 cm apart side
    by side in between; 6-camera ring at 320x240, 30 fps, with truth and silhouettes."""
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    clip, name = load_motion("procedural:turn_in_place:0")
    out = tmp_path_factory.mktemp("turn_in_place") / "rec"
    synthesize(clip, out, rig=make_rig("ring", size=(320, 240)), fps=30.0, seconds=2.5, start_s=0.8, seed=3,
               motion_name=name)
    return out


@pytest.fixture(scope="session")
def hand_behind_head(tmp_path_factory):
    """The procedural hand behind the head (seed 0), its first 0.6 s from 0.8 s as the suite plays
    it: standing, the right hand behind the head, the left at the hip; 6-camera ring at 320x240,
    30 fps, with truth and silhouettes. Without the legs on the shoes its cold start faced the
    body the wrong way (heading 150-160 deg off, hands and feet exchanged)."""
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    clip, name = load_motion("procedural:hand_behind_head:0")
    out = tmp_path_factory.mktemp("hand_behind_head") / "rec"
    synthesize(clip, out, rig=make_rig("ring", size=(320, 240)), fps=30.0, seconds=0.6, start_s=0.8, seed=3,
               motion_name=name)
    return out


@pytest.fixture(scope="session")
def jumping_jacks(tmp_path_factory):
    """The procedural jumping jacks (seed 0), 2 s from 0.8 s as the suite plays them: the arms
    swing sideways past the shoulders to overhead and back, the feet jump apart and together;
    6-camera ring at 320x240, 30 fps, with truth and silhouettes."""
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    clip, name = load_motion("procedural:jumping_jacks:0")
    out = tmp_path_factory.mktemp("jumping_jacks") / "rec"
    synthesize(clip, out, rig=make_rig("ring", size=(320, 240)), fps=30.0, seconds=2.0, start_s=0.8, seed=3,
               motion_name=name)
    return out
