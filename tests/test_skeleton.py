"""Skeleton formats: documented joint orders and parents, tree invariants, validation errors."""

import re

import pytest

from geometry import BODY25, COCO17, SHELF14, SHELF15, SKEL19, SKELETONS, SMPL24, STRUCTRI17, Skeleton

# Written out from the sources (OpenPose output doc, COCO keypoints, 4DA skel.h, Shelf ReadMe, SMPL
# kintree_table, Structural Triangulation's PARENT), not derived from geometry/_skeleton.py.
BODY25_ORDER = ["nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist",
                "mid_hip", "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye",
                "r_ear", "l_ear", "l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel"]
COCO17_ORDER = ["nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_shoulder", "r_shoulder", "l_elbow", "r_elbow",
                "l_wrist", "r_wrist", "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle"]
SKEL19_ORDER = ["mid_hip", "neck", "r_hip", "l_hip", "nose", "r_shoulder", "l_shoulder", "r_knee", "l_knee",
                "r_ear", "l_ear", "r_elbow", "l_elbow", "r_ankle", "l_ankle", "r_wrist", "l_wrist",
                "l_big_toe", "r_big_toe"]
STRUCTRI17_PARENTS = [-1, 2, 0, 0, 3, 4, 1, 0, 7, 16, 11, 12, 8, 8, 13, 14, 8]
SMPL24_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
ALL = list(SKELETONS.values())


def test_registry_and_counts():
    assert {name: s.num_joints for name, s in SKELETONS.items()} == {
        "BODY25": 25, "COCO17": 17, "SHELF14": 14, "SHELF15": 15, "SKEL19": 19, "STRUCTRI17": 17, "SMPL24": 24,
        "FLEX20": 20}
    assert all(SKELETONS[s.name] is s for s in ALL)


def test_documented_orders():
    assert list(BODY25.joints) == BODY25_ORDER
    assert list(COCO17.joints) == COCO17_ORDER
    assert list(SKEL19.joints) == SKEL19_ORDER
    assert list(SHELF15.joints) == list(SHELF14.joints) + ["mid_hip"]
    assert list(STRUCTRI17.parents) == STRUCTRI17_PARENTS
    assert list(SMPL24.parents) == SMPL24_PARENTS
    assert STRUCTRI17.joints[:4] == ("mid_hip", "r_knee", "r_hip", "l_hip") and STRUCTRI17.joints[16] == "neck_nose"
    assert SMPL24.joints[15] == "head" and SMPL24.joints[22:] == ("l_hand", "r_hand")


def test_shelf_order_matches_dataset_readme(data_root):
    readme = (data_root / "shelf" / "ReadMe.txt").read_text()
    rows = re.findall(r"^(\d\d)\s+(Right|Left|Bottom|Top) (\w+)\s*$", readme, flags=re.MULTILINE)
    names = []
    for number, side, part in rows:
        assert int(number) == len(names) + 1
        prefix = {"Right": "r_", "Left": "l_"}.get(side)
        names.append(prefix + part.lower() if prefix else f"head_{side.lower()}")
    assert names == list(SHELF14.joints)


@pytest.mark.parametrize("skeleton", ALL, ids=lambda s: s.name)
def test_tree_invariants(skeleton: Skeleton):
    order = skeleton.topological_order
    assert sorted(order) == list(range(skeleton.num_joints)) and order[0] == skeleton.root
    position = {j: k for k, j in enumerate(order)}
    assert all(position[p] < position[c] for p, c in skeleton.bones)
    assert len(skeleton.bones) == skeleton.num_joints - 1
    assert [c for _, c in skeleton.bones] == sorted(c for _, c in skeleton.bones)
    assert all(skeleton.parents[c] == p for p, c in skeleton.bones)


@pytest.mark.parametrize("skeleton", ALL, ids=lambda s: s.name)
def test_mirror_is_an_involution_that_swaps_sides(skeleton: Skeleton):
    m = skeleton.mirror
    assert all(m[m[i]] == i for i in range(skeleton.num_joints))
    for i, name in enumerate(skeleton.joints):
        other = skeleton.joints[m[i]]
        if name.startswith("l_"):
            assert other == "r_" + name[2:]
        elif name.startswith("r_"):
            assert other == "l_" + name[2:]
        else:
            assert m[i] == i
    lefts = [skeleton.joints[i] for i, _ in skeleton.left_right_pairs]
    assert all(n.startswith("l_") for n in lefts)
    assert len(skeleton.left_right_pairs) == sum(n.startswith("r_") for n in skeleton.joints)


def test_mirror_maps_parents_to_mirrored_parents():
    for s in ALL:
        for c, p in enumerate(s.parents):
            if p >= 0:
                assert s.parents[s.mirror[c]] == s.mirror[p], (s.name, s.joints[c])


@pytest.mark.parametrize("skeleton", ALL, ids=lambda s: s.name)
def test_mirror_bones_join_mirrored_joints(skeleton: Skeleton):
    for k, (parent, child) in enumerate(skeleton.bones):
        assert skeleton.bones[skeleton.mirror_bones[k]] == (skeleton.mirror[parent], skeleton.mirror[child])


def test_shelf15_pcp_parts_follow_the_protocol():
    # docs/protocols.md, "Parts and the PCP rule", Shelf15 indices; the order is 4DA's printout order.
    expected = [(9, 10), (7, 8), (10, 11), (6, 7), (3, 4), (1, 2), (4, 5), (0, 1), (12, 13), (14, 12)]
    assert [tuple(sorted(ix)) for ix in SHELF15.pcp_index] == [tuple(sorted(ix)) for ix in expected]
    assert [name for name, _, _ in SHELF15.pcp_parts][-2:] == ["head", "torso"]
    assert len(SHELF14.pcp_index) == 9  # no torso without a mid-hip


def test_index_raises_naming_the_joint():
    with pytest.raises(KeyError, match="head_top"):
        BODY25.index("head_top")


@pytest.mark.parametrize(
    ("joints", "parents", "message"),
    [
        (("a", "b", "c"), (-1, 2, 1), "tree"),  # b <-> c cycle, disconnected from the root
        (("a", "b"), (-1, -1), "exactly one root"),
        (("a", "b"), (1, 0), "exactly one root"),
        (("a", "b"), (-1, 5), "out of range"),
        (("a", "b"), (-1, 1), "self-parent"),
        (("a", "a"), (-1, 0), "duplicate"),
        (("a", "b"), (-1,), "parents"),
    ],
)
def test_invalid_skeletons_raise(joints, parents, message):
    with pytest.raises(ValueError, match=message):
        Skeleton("bad", joints, parents)


def test_pcp_part_with_unknown_joint_raises():
    with pytest.raises(ValueError, match="unknown joints"):
        Skeleton("bad", ("a", "b"), (-1, 0), pcp_parts=(("part", "a", "z"),))


def test_skeletons_are_hashable_static_metadata():
    assert hash(SHELF15) == hash(Skeleton(SHELF15.name, SHELF15.joints, SHELF15.parents, SHELF15.pcp_parts))
    assert SHELF14 != SHELF15
