import numpy as np
import pytest

import mocap


def _det(cands, ids):
    """Detections with two joint types; joint type 1 is always empty."""
    return mocap.Detections(
        joints=(np.asarray(cands, float).reshape(-1, 3), np.zeros((0, 3))),
        pafs=(np.zeros((len(cands), 0)),),
        person_ids=(np.asarray(ids, int), np.zeros(0, int)),
    )


def test_pad_detections_shapes_and_mask():
    frames = [[_det([[1, 2, 0.5], [3, 4, 0.9]], [1, 0]), _det([[5, 6, 0.7]], [-1])]]
    padded = mocap.pad_detections(frames)
    assert padded.xy.shape == (1, 2, 2, 2, 2)
    np.testing.assert_array_equal(padded.mask[0, :, 0], [[True, True], [True, False]])
    np.testing.assert_array_equal(padded.mask[0, :, 1], False)
    np.testing.assert_array_equal(padded.person_ids[0, 1, 0], [-1, -1])
    assert padded.xy[0, 0, 0, 1].tolist() == [3, 4]


def test_pad_detections_rejects_inconsistent_input():
    with pytest.raises(ValueError, match="max_candidates"):
        mocap.pad_detections([[_det([[1, 2, 0.5], [3, 4, 0.9]], [0, 1])]], max_candidates=1)
    with pytest.raises(ValueError, match="views"):
        mocap.pad_detections([[_det([[1, 2, 0.5]], [0])], [_det([[1, 2, 0.5]], [0])] * 2])


def test_oracle_keypoints_picks_each_persons_best_candidate():
    view0 = _det([[1, 2, 0.5], [3, 4, 0.9], [7, 8, 0.95], [9, 9, 0.3]], [1, 0, -1, 1])
    view1 = _det([[5, 6, 0.7]], [1])
    kp = mocap.oracle_keypoints(mocap.pad_detections([[view0, view1]]), num_people=2)
    assert kp.shape == (1, 2, 2, 2, 3)  # frames, views, people, joint types, (x, y, score)
    np.testing.assert_array_equal(kp[0, 0, 0, 0], [3, 4, 0.9])  # the spurious 0.95 is not person 0's
    np.testing.assert_array_equal(kp[0, 0, 1, 0], [1, 2, 0.5])  # best of person 1's two candidates
    np.testing.assert_array_equal(kp[0, 1, 0, 0], [0, 0, 0])  # person 0 unseen in view 1
    np.testing.assert_array_equal(kp[0, :, :, 1], 0)  # empty joint type
