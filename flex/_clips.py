"""The shipped CMU clips' roles in FLEX's training and experiments."""

import mocap

__all__ = ["TEST_CLIPS", "TRAIN_CLIPS", "VALIDATION_CLIPS"]

TEST_CLIPS: tuple[str, ...] = ("02_05_punch", "60_05_61_05_salsa")
"""Held out from training: FLEX's test clips (one single-person, one two-person clip)."""
VALIDATION_CLIPS: tuple[str, ...] = ("03_01_uneven",)
"""Held out from training and from the test: the training log's validation MPJPE."""
TRAIN_CLIPS: tuple[str, ...] = tuple(c for c in mocap.list_clips() if c not in TEST_CLIPS + VALIDATION_CLIPS)
