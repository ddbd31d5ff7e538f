"""Stable scene ids (syneepose/scene_ids.py): the numbering rules, without rendering."""

from syneepose.robots.catalog import load_catalog
from syneepose.scene_ids import Key, assign, fitting_segments, stream

CONFIGS = load_catalog().configurations
A, B = "panda+panda_hand", "ur5e+robotiq_2f85"  # 0th and 7th of the 18


def _keys(configs, segments):
    return [Key(c, s) for c in configs for s in range(segments)]


def test_a_fresh_data_set_is_numbered_as_before_the_record():
    for segments in (1, 3):
        scenes = assign({}, _keys((B, A), segments), segments, CONFIGS)
        assert scenes == {CONFIGS.index(k.config) * segments + k.segment: k for k in _keys((A, B), segments)}
        assert all(stream(key, segments, CONFIGS) == sid for sid, key in scenes.items())


def test_configurations_rendered_one_after_another_get_the_ids_of_one_run():
    first = assign({}, _keys((B,), 2), 2, CONFIGS)
    assert assign(first, _keys((A, B), 2), 2, CONFIGS) == assign({}, _keys((A, B), 2), 2, CONFIGS)


def test_more_segments_keep_every_id_and_take_the_ids_after_every_first_plan_number():
    first = assign({}, _keys((A, B), 1), 1, CONFIGS)
    assert first == {0: Key(A, 0), 7: Key(B, 0)}
    assert assign(first, _keys((A, B), 3), 1, CONFIGS) == {
        0: Key(A, 0), 7: Key(B, 0), 18: Key(A, 1), 19: Key(A, 2), 20: Key(B, 1), 21: Key(B, 2)}


def test_an_id_the_record_gives_or_a_folder_holds_is_not_given_to_a_key_after_the_first_plan_numbers():
    assert assign({0: Key(B, 3)}, [Key(A, 0), Key(A, 1)], 1, CONFIGS, folders={0, 25}) == {
        0: Key(B, 3), 26: Key(A, 0), 27: Key(A, 1)}
    assert assign({}, [Key(A, 0)], 1, CONFIGS, folders={0, 25}) == {0: Key(A, 0)}  # a folder without a frame


def test_the_segment_counts_a_data_set_from_before_the_record_fits():
    assert fitting_segments({7: B}, CONFIGS) == [1]
    assert fitting_segments({0: A, 15: B}, CONFIGS) == [2]
    assert fitting_segments({63: "panda+kinova_3f"}, CONFIGS) == [16, 17, 18, 19, 20, 21]
    assert fitting_segments({1: A}, CONFIGS) == [2, 3]  # and every count above: ambiguous
    assert fitting_segments({7: B, 0: "panda+kinova_3f"}, CONFIGS) == []
