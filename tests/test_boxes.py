"""Boxes from segmentation images and square crops."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ocplace.sim.boxes import boxes_from_segmentation, square_crop


def test_boxes_are_tight_around_each_object():
    segmentation = np.zeros((48, 64), np.int32)
    segmentation[10:20, 5:30] = 2
    segmentation[30:45, 40:41] = 1  # 15 px: below a threshold of 16
    segmentation[0:4, 60:64] = 3
    boxes = boxes_from_segmentation(segmentation, min_pixels=16)
    assert boxes.object_ids.tolist() == [2, 3]
    assert boxes.box_of(2).tolist() == [5, 10, 30, 20]
    assert boxes.box_of(3).tolist() == [60, 0, 64, 4]
    assert boxes.box_of(1) is None
    assert boxes.pixel_counts.tolist() == [250, 16]


@settings(max_examples=50, deadline=None)
@given(u0=st.integers(0, 60), v0=st.integers(0, 40), w=st.integers(1, 40), h=st.integers(1, 40))
def test_every_box_holds_all_pixels_of_its_object(u0, v0, w, h):
    segmentation = np.zeros((48, 64), np.int32)
    segmentation[v0 : v0 + h, u0 : u0 + w] = 7
    boxes = boxes_from_segmentation(segmentation, min_pixels=1)
    u_0, v_0, u_1, v_1 = boxes.box_of(7)
    inside = np.zeros_like(segmentation, bool)
    inside[v_0:v_1, u_0:u_1] = True
    assert np.all(inside[segmentation == 7]) and (u_1 - u_0) * (v_1 - v_0) == boxes.pixel_counts[0]


def test_square_crop_is_square_centred_and_resized():
    image = np.zeros((100, 200, 3), np.uint8)
    image[40:60, 90:130] = 255  # a 40 x 20 box
    crop = square_crop(image, np.array([90, 40, 130, 60]), padding=0.0)
    assert crop.shape == (40, 40, 3)
    assert crop[10:30].min() == 255 and crop[:10].max() == 0
    assert square_crop(image, np.array([90, 40, 130, 60]), size=32).shape == (32, 32, 3)


def test_square_crop_at_the_border_repeats_edge_pixels():
    image = np.full((50, 50, 3), 9, np.uint8)
    crop = square_crop(image, np.array([0, 0, 20, 10]), padding=0.25)
    assert crop.shape == (30, 30, 3) and np.all(crop == 9)
