"""mapping.frame.SegmentedFrame: the one frame type the mapping pipeline starts from."""
import numpy as np

from calnav.mapping.frame import SegmentedFrame


def test_labels_are_the_argmax_computed_once():
    logits = np.zeros((2, 3, 4), np.float32)
    logits[0, 1, 2] = 5.0
    logits[1, 2, 3] = 1.0
    f = SegmentedFrame(np.ones((2, 3), np.float32), np.eye(3), logits, np.zeros((2, 3, 3), np.uint8))
    expected = np.array([[0, 2, 0], [0, 0, 3]])
    np.testing.assert_array_equal(f.labels, expected)
    assert f.labels is f.labels                       # cached, not recomputed per access
    assert f.pose is None and f.semantic is None and f.index == -1   # a live frame: posed by its consumer
