"""The camera model agrees with itself and with what MuJoCo renders."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ocplace.sim.camera import DEFAULT_CAMERA, Camera
from ocplace.sim.mujoco_backend import MujocoScenes
from ocplace.sim.workspace import DEFAULT_TABLE


def test_intrinsics_match_the_design():
    camera = DEFAULT_CAMERA
    assert camera.fx == pytest.approx(320 / math.tan(math.radians(35)))
    assert camera.fx == pytest.approx(457.0, abs=0.05)
    assert (camera.cx, camera.cy) == (319.5, 239.5)


def test_whole_table_is_in_view():
    hx, hy = DEFAULT_TABLE.half_extents
    corners = DEFAULT_CAMERA.table_to_pixel(np.array([[-hx, -hy], [hx, hy]]))
    assert np.all(corners >= 0) and corners[1, 0] <= 639 and corners[0, 1] <= 479


def test_image_axes_follow_the_world_frame():
    left, right, back = DEFAULT_CAMERA.table_to_pixel(np.array([[-0.1, 0.0], [0.1, 0.0], [0.0, 0.1]]))
    assert left[0] < right[0]
    assert back[1] < DEFAULT_CAMERA.cy  # +y (away from the viewer) is the top of the image


@settings(max_examples=200, deadline=None)
@given(u=st.floats(0, 639), v=st.floats(0, 479), depth=st.floats(0.2, 1.5))
def test_pixel_depth_round_trip(u, v, depth):
    camera = Camera()
    world = camera.pixel_to_world(np.array([u, v]), np.array(depth))
    assert np.abs(camera.world_to_pixel(world) - [u, v]).max() < 0.5
    assert camera.world_to_camera(world)[2] == pytest.approx(depth)


@pytest.fixture(scope="module")
def empty_arena():
    with MujocoScenes([], {}) as arena:
        arena.activate(())
        yield arena


def test_rendered_depth_back_projects_onto_the_table_plane(empty_arena):
    rgb, depth, segmentation = empty_arena.render(())
    camera = empty_arena.config.camera
    vs, us = np.mgrid[0 : camera.height, 0 : camera.width]
    world = camera.pixel_to_world(np.stack([us, vs], axis=-1), depth)
    on_table = np.all(np.abs(world[..., :2]) < np.asarray(DEFAULT_TABLE.half_extents) - 0.005, axis=-1)
    assert on_table.mean() > 0.85
    assert np.abs(world[on_table][:, 2]).max() < 0.001
    assert np.all(segmentation == 0)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8


def test_table_edges_land_where_the_model_projects_them(empty_arena):
    _, depth, _ = empty_arena.render(())
    camera = empty_arena.config.camera
    hx, _ = DEFAULT_TABLE.half_extents
    u_edge = camera.table_to_pixel(np.array([hx, 0.0]))[0]
    row = depth[int(camera.cy)]
    first_off_table = int(np.argmax(row[int(camera.cx) :] > 1.0)) + int(camera.cx)
    assert abs(first_off_table - u_edge) <= 1.0
