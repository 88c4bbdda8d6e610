"""The `python -m jaxsat demo` command: report, picture, and the command line itself."""

from __future__ import annotations

import re
import subprocess
import sys

import jax
import numpy as np
import pytest

from jaxsat.__main__ import main

CASES = ("2d-polygons", "3d-boxes", "3d-hulls")
# case, pairs, collide, compile f32, compile f64, pairs/s, max|depth err| (all, colliding),
# max normal angle
ROW = re.compile(r"^(?P<case>\S+)\s+(?P<pairs>\d+)\s+(?P<collide>\d+)\s+[\d.]+s\s+[\d.]+s\s+"
                 r"(?P<rate>\S+)\s+(?P<depth_error>\S+)\s+(?P<hit_error>\S+)\s+(?P<angle>\S+) rad$",
                 re.MULTILINE)


@pytest.fixture(autouse=True)
def restore_x64():
    """The demo enables float64 globally; put the setting back for the other tests."""
    before = jax.config.read("jax_enable_x64")
    yield
    jax.config.update("jax_enable_x64", before)


@pytest.mark.slow
def test_demo_prints_every_case_and_saves_a_png(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    output = tmp_path / "demo.png"
    assert main(["demo", "--pairs", "64", "--repeats", "1", "--output", str(output)]) == 0
    report = capsys.readouterr().out

    assert output.is_file()
    assert output.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"saved picture: {output}" in report
    rows = {match["case"]: match for match in ROW.finditer(report)}
    assert set(rows) == set(CASES), report
    for case, row in rows.items():
        assert int(row["pairs"]) == 64, case
        assert 0 <= int(row["collide"]) <= 64, case
        assert float(row["rate"]) > 0, case
        # float32 against float64, shapes about 1 unit across
        assert float(row["depth_error"]) < 1e-3, case
        assert float(row["hit_error"]) < 1e-4, case
        assert float(row["angle"]) < 1e-2, case


@pytest.mark.slow  # runs the demo's 2D case
def test_demo_without_matplotlib_explains_how_to_install_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # makes `import matplotlib` fail
    output = tmp_path / "demo.png"
    args = ["demo", "--pairs", "16", "--repeats", "1", "--cases", "2d-polygons",
            "--output", str(output)]
    assert main(args) == 0
    report = capsys.readouterr().out
    assert "2d-polygons" in report
    assert "jaxsat[plot]" in report
    assert not output.exists()


@pytest.mark.slow
def test_demo_no_plot_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--pairs", "16", "--repeats", "1", "--cases", "3d-boxes",
                 "--no-plot"]) == 0
    assert "3d-boxes" in capsys.readouterr().out
    assert not list(tmp_path.iterdir())


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "demo" in capsys.readouterr().out


@pytest.mark.parametrize("args", [["--help"], ["demo", "--help"]])
def test_help_from_the_command_line(args):
    result = subprocess.run([sys.executable, "-m", "jaxsat", *args], capture_output=True,
                            text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    assert "demo" in result.stdout
    assert "usage" in result.stdout.lower()


# What the picture draws: `pair_drawing` for one pair, `draw_scenes` for the panels.

def _x64():
    jax.config.update("jax_enable_x64", True)  # restored by restore_x64


def _pose(dim, translation, angle=0.0):
    """A pose from a translation and a rotation by `angle` (about z in 3D)."""
    import jaxsat

    translation = np.asarray(translation, np.float64)
    if dim == 2:
        return jaxsat.pose2(translation[0], translation[1], angle)
    return jaxsat.pose3(translation, np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]))


def _box(dim, half_extents):
    import jaxsat

    return jaxsat.box(np.asarray(half_extents[:dim], np.float64))


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])  # 3D: compiles
def test_separated_pair_draws_the_closest_points_and_their_distance(dim):
    """Two axis-aligned boxes apart along x by a gap of 0.3: the drawn segment joins a's face
    at x = 0.5 to b's at x = 0.8 and is 0.3 long, as the label says."""
    from jaxsat._demo import pair_drawing

    _x64()
    a, b = _box(dim, [0.5, 0.4, 0.3]), _box(dim, [0.2, 0.3, 0.25])
    drawing = pair_drawing(a, _pose(dim, [0.0, 0.0, 0.0][:dim]), b,
                           _pose(dim, [1.0, 0.1, 0.05][:dim]))
    assert not drawing.colliding
    np.testing.assert_allclose(drawing.start[0], 0.5, atol=1e-12)
    np.testing.assert_allclose(drawing.end[0], 0.8, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(drawing.end - drawing.start), 0.3, atol=1e-12)
    assert drawing.value == pytest.approx(0.3, abs=1e-12)
    assert drawing.label == "distance 0.300"
    np.testing.assert_array_equal(drawing.shift, 0.0)


def test_separated_corners_draw_the_euclidean_distance_not_the_sat_gap():
    """Corner to corner, with gaps 0.3 along x and 0.4 along y: the distance is 0.5, while the
    SAT gap that `penetration` reports (the demo's old arrow) is only 0.4."""
    import jaxsat
    from jaxsat._demo import pair_drawing

    _x64()
    a, b = _box(2, [0.5, 0.5]), _box(2, [0.25, 0.25])
    pose_a, pose_b = _pose(2, [0.0, 0.0]), _pose(2, [1.05, 1.15])
    assert float(jaxsat.penetration(a, pose_a, b, pose_b).depth) == pytest.approx(-0.4)
    drawing = pair_drawing(a, pose_a, b, pose_b)
    assert not drawing.colliding
    np.testing.assert_allclose(drawing.start, [0.5, 0.5], atol=1e-12)
    np.testing.assert_allclose(drawing.end, [0.8, 0.9], atol=1e-12)
    assert drawing.value == pytest.approx(0.5, abs=1e-12)
    assert drawing.label == "distance 0.500"


def _colliding_pairs():
    """(name, a, pose_a, b, pose_b): hand-made overlaps in 2D and 3D, turned and not."""
    import jaxsat

    hexagon = jaxsat.regular_polygon(6, 0.5)
    return [
        ("2d boxes", _box(2, [0.5, 0.4]), _pose(2, [0.0, 0.0]), _box(2, [0.3, 0.2]),
         _pose(2, [0.7, 0.1])),
        ("2d turned", hexagon, _pose(2, [0.2, -0.1], 0.3), _box(2, [0.4, 0.15]),
         _pose(2, [-0.2, 0.35], 1.1)),
        ("3d boxes", _box(3, [0.5, 0.4, 0.3]), _pose(3, [0.0, 0.0, 0.0]),
         _box(3, [0.3, 0.2, 0.25]), _pose(3, [0.1, -0.4, 0.45], 0.7)),
    ]


@pytest.mark.parametrize(
    "pair", [pair if pair[0] == "2d boxes" else pytest.param(pair, marks=pytest.mark.slow)
             for pair in _colliding_pairs()], ids=lambda pair: pair[0])  # one fast, 2-4 s each
def test_colliding_arrow_is_the_smallest_move_of_b_that_separates_the_pair(pair):
    """Moving b by the arrow (and a hair more) separates the pair; 0.1% less does not."""
    import jaxsat
    from jaxsat._demo import pair_drawing

    _x64()
    _, a, pose_a, b, pose_b = pair
    drawing = pair_drawing(a, pose_a, b, pose_b)

    def moved(scale):
        return jaxsat.Pose(pose_b.translation + scale * drawing.shift, pose_b.rotation)

    assert drawing.colliding and drawing.value > 0.01
    assert drawing.label == f"depth {drawing.value:.3f}"
    np.testing.assert_allclose(np.linalg.norm(drawing.shift), drawing.value, rtol=1e-12)
    assert bool(jaxsat.intersects(a, pose_a, b, pose_b))
    assert not bool(jaxsat.intersects(a, pose_a, b, moved(1 + 1e-6)))
    assert bool(jaxsat.intersects(a, pose_a, b, moved(1 - 1e-3)))
    # The arrow starts on b and ends on a: its tail is a point of b, its head a point of a.
    assert float(jaxsat.signed_distance(b, moved(1.0), a, pose_a)) == pytest.approx(0, abs=1e-9)
    for shape, pose, point in ((b, pose_b, drawing.start), (a, pose_a, drawing.end)):
        dot = jaxsat.sphere(1e-9) if shape.dim == 3 else jaxsat.circle(1e-9)
        here = _pose(shape.dim, point)
        assert float(jaxsat.signed_distance(shape, pose, dot, here)) <= 1e-8


def test_faces_of_a_box_and_of_a_hull_are_outward_and_cover_the_surface():
    """The 3D panels' faces: a box has 6 outward quadrilaterals, and a hull's faces add up to
    the area of its convex hull (scipy)."""
    import jaxsat
    from jaxsat._demo import _world_faces

    _x64()
    spatial = pytest.importorskip("scipy.spatial")

    def check(shape, pose, count=None):
        faces = _world_faces(shape, pose)
        centre = np.asarray(pose.translation)
        area = 0.0
        for loop, normal in faces:
            np.testing.assert_allclose(loop @ normal, loop[0] @ normal, atol=1e-9)  # planar
            assert (loop.mean(axis=0) - centre) @ normal > 0  # outward
            fan = np.cross(loop[1:-1] - loop[0], loop[2:] - loop[0])
            assert np.all(fan @ normal > 0)  # ordered around the face: a convex loop
            area += 0.5 * np.sum(fan @ normal)
        if count is not None:
            assert len(faces) == count and all(len(loop) == 4 for loop, _ in faces)
        world = np.asarray(pose.apply(shape.vertices))[np.asarray(shape.vertex_mask)]
        assert area == pytest.approx(spatial.ConvexHull(world).area, rel=1e-9)

    check(_box(3, [0.5, 0.4, 0.3]), _pose(3, [0.2, -0.1, 0.3], 0.7), count=6)
    points = np.random.default_rng(1).normal(size=(20, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    check(jaxsat.polyhedron(points * [0.8, 0.5, 0.3], max_vertices=24),
          _pose(3, [1.0, 0.5, -0.2], 2.0))


@pytest.mark.slow
def test_picture_titles_give_the_depth_and_the_exact_distance():
    """Every 2D panel of the demo's picture is a colliding pair (top row) or a separated one
    (bottom row) and its title ends with the depth, or with the distance of `signed_distance`
    (not the SAT gap)."""
    pytest.importorskip("matplotlib")
    import jaxsat
    from jaxsat._demo import choose_panels, draw_scenes, make_scene, run_case

    _x64()
    scene = make_scene("2d-polygons", 64)
    scenes = {"2d-polygons": scene}
    results = {"2d-polygons": run_case(scene, repeats=1)}
    figure = draw_scenes(scenes, results)
    panels = choose_panels(results)
    assert [(panel.row, panel.column) for panel in panels] == [(r, c) for r in (0, 1)
                                                              for c in range(3)]
    titles = [axes.get_title() for axes in figure.axes]
    assert len(titles) == len(panels)
    for panel, title in zip(panels, titles, strict=True):
        assert panel.index is not None, title
        pair = [jax.tree.map(lambda leaf, i=panel.index: leaf[i], part)
                for part in scene.arguments()]
        distance = float(jaxsat.signed_distance(*pair))
        if panel.row == 0:
            assert distance < 0, title
            assert title.endswith(f"depth {-distance:.3f}"), title
        else:
            assert distance > 0, title
            assert title.endswith(f"distance {distance:.3f}"), title
