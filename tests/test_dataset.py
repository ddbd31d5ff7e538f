"""kernel.dataset: the layout of a rendered data set, read back through one object."""

import pytest

from kernel.bop import read_scene
from kernel.dataset import Dataset
from kernel.errors import UserError
from tests.conftest import TINY_CONFIGS


def test_layout_of_a_rendered_dataset(tiny_dataset):
    dataset = Dataset(tiny_dataset)
    assert dataset.split == "test" and dataset.split_dir == tiny_dataset / "test"
    scenes = dataset.scenes()
    assert [s.scene_id for s in scenes] == sorted(dataset.scene_dirs()) and len(scenes) == len(TINY_CONFIGS)
    assert {s.config for s in scenes} == set(TINY_CONFIGS)
    assert dataset.obj_ids() == list(range(1, 7))
    for scene in scenes:
        assert Dataset.of_scene(scene.path) == dataset
        assert dataset.model_path(scene.meta.obj_id).is_file() and dataset.eval_model_path(scene.meta.obj_id).is_file()
        assert scene.im_ids == read_scene(scene.path)[1]
        frame = scene.frame(scene.im_ids[-1])
        assert (scene.depth(frame.im_id) == frame.depth).all()
        assert (scene.gt_poses()[frame.im_id] == frame.T_cam_ee).all()
    assert (dataset.templates_dir / "robotiq_2f85_12x4_96px" / "templates.json").is_file()


def test_missing_scene_and_depth_folder_are_one_line(tiny_dataset):
    dataset = Dataset(tiny_dataset)
    with pytest.raises(UserError, match="scene 999 is not in"):
        dataset.scene(999)
    scene = dataset.scenes()[0]
    with pytest.raises(UserError, match="depth_ir.*must sit beside depth/"):
        scene.depth(scene.im_ids[0], "depth_ir")
