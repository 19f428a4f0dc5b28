"""Simulator pairs for the transfer model: the source rollout's controls against the same seed
rendered in another look, with identical geometry and motion."""

import numpy as np
import pytest

from tasks.controls.render import Recorder
from tasks.controls.video import frame_controls
from tasks.sim.episode import rollout
from models.transfer import OBJECT_CLASSES as MODEL_OBJECT_CLASSES
from tasks.transfer.pairs import (LOOKS, OBJECT_CLASSES, OBJECT_GROUPS, SEG_CLASSES, SEG_GROUPS, look_manifest, make_pairs,
                                  seg_classes, source_manifest)
from tasks.manifests import load as load_manifest

from tests.support import MANIFESTS

pytestmark = pytest.mark.slow  # simulates and renders MuJoCo episodes


@pytest.fixture(scope="module")
def pairs():
    # push_closeup: its side camera at 64 px, 10 fps; 1 s is 10 frames and the arm moves.
    return make_pairs(load_manifest(MANIFESTS / "push_closeup.yaml"), [21], horizon_s=1.0)


def test_every_look_has_the_source_motion(pairs):
    assert [p.prompt for p in pairs] == list(LOOKS)
    source = pairs[0]
    assert np.abs(np.diff(source.frames.astype(int), axis=0)).max() > 50  # the arm moves in view
    for pair in pairs:
        assert np.array_equal(pair.source_pose, pair.target_pose), pair.prompt
        assert pair.frames.shape == (10, 64, 64, 3) and pair.seg.shape == pair.edges.shape == (10, 64, 64)
        assert pair.seg.max() < SEG_CLASSES
        for name in ("edges", "blur", "depth_mm", "seg", "source_frames"):  # one set of controls for every look
            assert getattr(pair, name) is getattr(source, name)
    assert np.array_equal(source.source_frames, source.frames)  # the frame control: the source look's frames


def test_looks_differ_from_the_source_where_the_scene_is(pairs):
    source = pairs[0].frames.astype(int)
    means = {p.prompt: p.frames.mean() for p in pairs}
    assert means["very dim"] < means["dim"] < means["nominal"]
    for pair in pairs[1:]:
        assert np.abs(pair.frames.astype(int) - source).mean() > 2, pair.prompt


def test_the_package_segment_lines_up_with_the_colour_shifted_package(pairs):
    """Colour shift recolours every material; the package's pixels (segmentation class 1) change
    colour in the stressed frame exactly where the source segmentation puts them."""
    source, shifted = pairs[0], next(p for p in pairs if p.prompt == "colour shift")
    package = source.seg == SEG_GROUPS.index(("package",))
    assert package.any()
    diff = np.abs(shifted.frames.astype(int) - source.frames.astype(int)).sum(-1)
    assert diff[package].mean() > 10


def test_a_look_renders_the_same_segmentation_as_the_source():
    """The strongest form of "same geometry": every pixel's object is the same in both looks."""
    parent = load_manifest(MANIFESTS / "push_closeup.yaml").model_copy(update={"horizon_s": 0.5})
    ids = []
    for manifest in (source_manifest(parent), look_manifest(parent, "textures")):
        recorder = Recorder()
        rollout(manifest, 21, on_frame=recorder)
        ids.append(recorder.rendered().ids["side"])
    assert np.array_equal(*ids)


def test_controls_are_the_controls_module_s(pairs):
    source = pairs[0]
    assert np.array_equal(frame_controls(source.frames)["edges"], source.edges)


def test_manifests_keep_all_but_the_look():
    parent = load_manifest(MANIFESTS / "bin_pick_dim_forklift.yaml")
    kinds = {s.kind for s in parent.stressors} - {"appearance", "dim_light"}
    assert {s.kind for s in source_manifest(parent).stressors} == kinds
    dim = look_manifest(parent, "dim")
    assert {s.kind for s in dim.stressors} == kinds | {"dim_light"} and dim.stressor("dim_light").lux == 200
    with pytest.raises(ValueError, match="unknown look"):
        look_manifest(parent, "sepia")


def test_seg_classes_group_the_legend():
    legend = ("background", "package", "bin", "robot", "distractor_0")
    assert seg_classes(np.arange(5, dtype=np.uint8), legend).tolist() == [0, 1, 3, 2, SEG_CLASSES - 1]


def test_object_classes_keep_table_and_floor_apart():
    legend = ("background", "package", "floor", "goal", "robot", "table", "distractor_0")
    ids = np.arange(7, dtype=np.uint8)
    assert seg_classes(ids, legend).tolist() == [0, 1, 3, 4, 2, 3, SEG_CLASSES - 1]  # table and floor: one class
    assert seg_classes(ids, legend, OBJECT_GROUPS).tolist() == [0, 1, 4, 6, 2, 3, OBJECT_CLASSES - 1]
    assert OBJECT_CLASSES == MODEL_OBJECT_CLASSES


def test_pairs_carry_both_segmentations():
    pair = make_pairs(load_manifest(MANIFESTS / "push_closeup.yaml"), [21], prompts=("nominal",), horizon_s=0.3)[0]
    assert pair.objects.shape == pair.seg.shape
    floor_or_table = np.isin(pair.seg, [3])
    assert set(np.unique(pair.objects[floor_or_table]).tolist()) == {3, 4}  # the grouped class split in two


def test_several_seeds_each_get_their_own_pairs():
    pairs = make_pairs(load_manifest(MANIFESTS / "push_closeup.yaml"), [21, 22], prompts=("nominal", "dim"),
                       horizon_s=0.3)
    assert [(p.seed, p.prompt) for p in pairs] == [(21, "nominal"), (21, "dim"), (22, "nominal"), (22, "dim")]
    assert not np.array_equal(pairs[0].frames, pairs[2].frames)  # the seeds place the package differently
