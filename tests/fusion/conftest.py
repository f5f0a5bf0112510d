"""Short studio recordings of a backwards walk, rendered once per session (identity tests)."""

import pytest

BACKWARDS_WALK_FRAMES = 45


def _render(tmp_path_factory, tag: str, motion, variant: str | None, seconds: float, start_s: float):
    """``motion`` (a BVH path or ``procedural:<name>:<seed>``, ``studio.variants.load_motion``)
    rendered for ``seconds`` from ``start_s`` by the 6-camera ring at 320x240, 30 fps, render
    seed 3, with truth and silhouettes: the recording directory."""
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    clip, name = load_motion(motion, variant)
    out = tmp_path_factory.mktemp(tag) / "rec"
    synthesize(clip, out, rig=make_rig("ring", size=(320, 240)), fps=30.0, seconds=seconds, start_s=start_s, seed=3,
               motion_name=name)
    return out


def _backwards_walk(tmp_path_factory, data_dir, frames: int):
    return _render(tmp_path_factory, "backwards_walk", data_dir / "bvh" / "cmu" / "cmu_131_01_start_walk_stop.bvh",
                   "reversed", frames / 30.0, 2.0)


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
    kick = data_dir / "bvh" / "bandai_namco" / "dataset-1_kick_normal_001.bvh"
    return _render(tmp_path_factory, "kick_reversed", kick, "reversed", 0.5, 0.0)


@pytest.fixture(scope="session")
def turn_in_place(tmp_path_factory):
    """The procedural turn on the spot (seed 0), 2.5 s from 0.8 s as the suite plays it: the feet
    step apart and together, touching at frames 36-40 and 62-68 and standing 20-25 cm apart side
    by side in between; 6-camera ring at 320x240, 30 fps, with truth and silhouettes."""
    return _render(tmp_path_factory, "turn_in_place", "procedural:turn_in_place:0", None, 2.5, 0.8)


@pytest.fixture(scope="session")
def hand_behind_head(tmp_path_factory):
    """The procedural hand behind the head (seed 0), its first 0.6 s from 0.8 s as the suite plays
    it: standing, the right hand behind the head, the left at the hip; 6-camera ring at 320x240,
    30 fps, with truth and silhouettes. Without the legs on the shoes its cold start faced the
    body the wrong way (heading 150-160 deg off, hands and feet exchanged)."""
    return _render(tmp_path_factory, "hand_behind_head", "procedural:hand_behind_head:0", None, 0.6, 0.8)


@pytest.fixture(scope="session")
def hand_held_behind_head(tmp_path_factory):
    """The procedural hand behind the head (seed 0), 2 s from 1.0 s: the right hand reaches up
    (0.49 m from the head's centre) and from frame 18 rests behind the head (0.125 m, still);
    6-camera ring at 320x240, 30 fps, with truth and silhouettes."""
    return _render(tmp_path_factory, "hand_held_behind_head", "procedural:hand_behind_head:0", None, 2.0, 1.0)


@pytest.fixture(scope="session")
def jumping_jacks(tmp_path_factory):
    """The procedural jumping jacks (seed 0), 2 s from 0.8 s as the suite plays them: the arms
    swing sideways past the shoulders to overhead and back, the feet jump apart and together;
    6-camera ring at 320x240, 30 fps, with truth and silhouettes."""
    return _render(tmp_path_factory, "jumping_jacks", "procedural:jumping_jacks:0", None, 2.0, 0.8)
