"""Benchmark robots and user meshes (softrom_gym.robots)."""

import numpy as np
import pytest
import trimesh

from softrom_gym.robots import ROBOTS, Robot, from_mesh, make_robot

# Node counts of the paper's Table I.
TABLE_I = {"cross": 623, "beam": 426, "quadruped": 1315, "tripod": 1417}


@pytest.mark.parametrize("name", sorted(TABLE_I))
def test_node_counts_match_table_i(name):
    robot = ROBOTS[name]()
    assert abs(robot.num_nodes / TABLE_I[name] - 1.0) <= 0.25, robot


@pytest.mark.parametrize("name", sorted(TABLE_I))
def test_robot_mesh_is_valid(name):
    robot = ROBOTS[name]()
    p = robot.nodes[robot.tets]
    vol = np.linalg.det(p[:, 1:] - p[:, :1]) / 6
    assert np.all(vol > 0)
    assert robot.nodes[:, 2].min() == pytest.approx(0.0)
    surface = robot.surface()
    assert isinstance(surface, trimesh.Trimesh)
    assert surface.is_watertight
    assert surface.volume == pytest.approx(robot.volume, rel=1e-9)  # outward winding
    # Only boundary nodes are contact candidates, and every node is used.
    assert 0 < len(robot.surface_nodes) < robot.num_nodes
    assert np.array_equal(np.unique(robot.tets), np.arange(robot.num_nodes))
    fem = robot.fem_model()
    assert fem.mass.sum() == pytest.approx(robot.mass)


def test_shapes_are_recognisable():
    c = make_robot("cross")
    extent = np.ptp(c.nodes, axis=0)
    assert extent[0] == pytest.approx(extent[1]) and extent[2] < 0.2 * extent[0]
    # The plus shape leaves its corners empty: area is well under the bounding square's.
    assert c.volume < 0.5 * extent.prod()
    # The quadruped's and tripod's legs: the footprint at z = 0 has 4 / 3 separate pieces.
    for name, legs in (("quadruped", 4), ("tripod", 3)):
        r = make_robot(name)
        base = r.nodes[r.nodes[:, 2] < 1e-9][:, :2]
        pitch = r.metadata["pitch"]
        ids = np.arange(len(base))
        for _ in range(len(base)):  # label propagation over grid neighbours
            d = np.abs(base[:, None] - base[None]).max(-1) <= pitch * 1.01
            ids = np.min(np.where(d, ids[None], len(base)), axis=1)
        assert len(np.unique(ids)) == legs, name


def test_resolution_scales_node_count():
    assert make_robot("beam", resolution=48).num_nodes > 2 * make_robot("beam").num_nodes


def test_unknown_robot_lists_valid_ones():
    with pytest.raises(ValueError, match=r"unknown robot 'octopus'; valid robots: \['beam'"):
        make_robot("octopus")


def test_bad_resolution():
    with pytest.raises(ValueError, match="resolution must be >= 2"):
        make_robot("cross", resolution=1)
    with pytest.raises(TypeError, match="resolution must be an integer"):
        make_robot("cross", resolution=2.5)
    with pytest.raises(ValueError, match="too coarse"):
        make_robot("beam", resolution=4)


@pytest.mark.parametrize(("name", "resolution"), [("quadruped", 10), ("tripod", 14), ("beam", 12)])
def test_a_resolution_that_splits_the_shape_is_refused(name, resolution):
    # At these resolutions a part boundary falls on a layer of voxel centres, which is left
    # empty: the quadruped kept its body and lost its legs, the beam became one foot voxel.
    with pytest.raises(ValueError, match=rf"resolution {resolution} splits the {name} into"):
        make_robot(name, resolution=resolution)
    assert make_robot(name, resolution=resolution + 1).num_nodes > 50  # the next one is whole


def test_from_mesh_box_volume():
    box = trimesh.creation.box((0.3, 0.2, 0.1))
    robot = from_mesh(box, resolution=20)
    assert robot.volume == pytest.approx(box.volume, rel=0.10)
    assert isinstance(robot, Robot) and robot.name == "mesh"


def test_from_mesh_sphere_volume():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    robot = from_mesh(sphere, resolution=16)
    assert robot.volume == pytest.approx(sphere.volume, rel=0.10)
    assert robot.surface().is_watertight


def test_from_mesh_reads_files(tmp_path):
    path = tmp_path / "capsule.stl"
    trimesh.creation.capsule(height=0.3, radius=0.1).export(path)
    robot = from_mesh(path, resolution=10, youngs_modulus=2e5)
    assert robot.name == "capsule" and robot.youngs_modulus == 2e5


def test_a_malformed_mesh_file_is_named(tmp_path):
    # trimesh's own errors named no file: "KeyError: 'y'", "IndexError: index 8 is out of
    # bounds ...", "Not a ply file!", a JSONDecodeError for a truncated .glb
    (tmp_path / "faces.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    (tmp_path / "header.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n"
    )
    (tmp_path / "zeros.ply").write_bytes(bytes(100))
    glb = trimesh.exchange.gltf.export_glb(trimesh.Scene(trimesh.creation.box((0.1, 0.1, 0.1))))
    (tmp_path / "cut.glb").write_bytes(glb[: len(glb) // 2])
    for name in ("faces.obj", "header.ply", "zeros.ply", "cut.glb"):
        with pytest.raises(ValueError, match=rf"cannot read '.*{name}' as a mesh \(the file is "
                           rf"malformed\?\): \w+"):  # fmt: skip
            from_mesh(tmp_path / name, 4)


def test_a_scene_is_meshed_as_its_file_is(tmp_path):
    # trimesh.load("robot.glb") gives a Scene, which was "mesh must be a file path or a
    # trimesh.Trimesh, got Scene" (and "unknown robot" in the env) while the path itself
    # was read, its geometry concatenated
    scene = trimesh.Scene()
    scene.add_geometry(
        trimesh.creation.box((0.2, 0.1, 0.05)),
        transform=trimesh.transformations.rotation_matrix(np.pi / 2, (0, 0, 1)),
    )
    scene.export(tmp_path / "robot.glb")
    from_file = from_mesh(tmp_path / "robot.glb", 8)
    from_scene = from_mesh(trimesh.load(tmp_path / "robot.glb"), 8)
    np.testing.assert_array_equal(from_scene.nodes, from_file.nodes)
    np.testing.assert_array_equal(from_scene.tets, from_file.tets)
    assert np.ptp(from_scene.nodes, axis=0) == pytest.approx((0.1, 0.2, 0.05))  # turned
    with pytest.raises(ValueError, match="the trimesh.Scene holds no triangle mesh"):
        from_mesh(trimesh.Scene(), 8)


def test_from_mesh_rejects_open_mesh():
    box = trimesh.creation.box((1, 1, 1))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)
    with pytest.raises(ValueError, match="mesh is not watertight"):
        from_mesh(open_box)


def test_from_mesh_bad_arguments(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        from_mesh(tmp_path / "missing.stl")
    (tmp_path / "notes.txt").write_text("not a mesh\n")
    with pytest.raises(ValueError, match=r"cannot read .*notes.txt.* as a mesh: use .*\.stl"):
        from_mesh(tmp_path / "notes.txt")
    with pytest.raises(
        TypeError, match="mesh must be a file path, a trimesh.Trimesh or a trimesh.Scene, got int"
    ):
        from_mesh(42)
    with pytest.raises(TypeError, match="unknown material parameter"):
        from_mesh(trimesh.creation.box((1, 1, 1)), stiffness=3)
    with pytest.raises(ValueError, match="is a directory, not a mesh file"):
        from_mesh(tmp_path)
    box = trimesh.creation.box((0.2, 0.1, 0.05))
    for material, error, message in (
        ({"youngs_modulus": -1.0}, ValueError, "youngs_modulus must be a finite number > 0"),
        ({"poisson_ratio": 0.7}, ValueError, r"poisson_ratio must lie in \(-1, 0.5\), got 0.7"),
        # (the open bound itself: guards `< 0.5` becoming `<= 0.5`)
        ({"poisson_ratio": 0.5}, ValueError, r"poisson_ratio must lie in \(-1, 0.5\), got 0.5"),
        ({"density": float("nan")}, ValueError, "density must be a finite number > 0, got nan"),
        ({"youngs_modulus": "5e4"}, TypeError, "youngs_modulus must be a real number, got '5e4'"),
    ):
        with pytest.raises(error, match=message):
            from_mesh(box, 4, **material)
    # near incompressibility linear tetrahedra lock: allowed, with a warning that says so
    with pytest.warns(UserWarning, match="poisson_ratio = 0.49: linear tetrahedra lock"):
        from_mesh(box, 4, poisson_ratio=0.49)
    from_mesh(box, 4, poisson_ratio=0.45)  # the advised nu <= 0.45 is silent (warnings fail)


def test_from_mesh_refuses_overlapping_shells():
    # Two boxes concatenated, not unioned: each is watertight, but inside-outside is undefined
    # where they overlap (the ray test came out differently from call to call: 0.12-0.26 kg
    # for a 0.875 kg cross).
    bars = [trimesh.creation.box((0.2, 0.05, 0.05)), trimesh.creation.box((0.05, 0.2, 0.05))]
    with pytest.raises(ValueError, match="some overlap .a voxel centre lies inside two of them"):
        from_mesh(trimesh.util.concatenate(bars), 10)
    # separate shells whose bounding boxes meet (diagonally placed) do not overlap
    spheres = [trimesh.creation.icosphere(3, 0.1), trimesh.creation.icosphere(3, 0.08)]
    spheres[1].apply_translation((0.15, 0.15, 0.0))
    with pytest.warns(UserWarning, match="the mesh has 2 separate bodies"):
        from_mesh(trimesh.util.concatenate(spheres), 20)
    # a cavity (an inner shell facing inwards) is not an overlap: a hollow box
    inner = trimesh.creation.box((0.1, 0.1, 0.1))
    inner.invert()
    hollow = from_mesh(trimesh.util.concatenate([trimesh.creation.box((0.2, 0.2, 0.2)), inner]), 10)
    assert 0.2**3 - 0.14**3 < hollow.volume < 0.2**3 - 0.06**3


def test_an_inside_out_mesh_is_read_as_the_solid_it_bounds():
    # Every face wound inwards (a mirrored export): the overlap test counted the shells as
    # cavities, so two crossing bars were not refused but hollowed where they cross (even ray
    # parity) and one arm kept, with "raise resolution to keep thin parts"
    bars = [trimesh.creation.box((0.2, 0.05, 0.05)), trimesh.creation.box((0.05, 0.2, 0.05))]
    crossing = trimesh.util.concatenate(bars)
    crossing.invert()
    with pytest.raises(ValueError, match="some overlap .a voxel centre lies inside two of them"):
        from_mesh(crossing, 10)
    two = [trimesh.creation.box((0.1, 0.1, 0.1)) for _ in range(2)]
    two[1].apply_translation((0.3, 0.0, 0.0))
    apart = trimesh.util.concatenate(two)
    apart.invert()
    with pytest.warns(UserWarning, match="dropped 125 of 250 voxels: the mesh has 2 separate"):
        from_mesh(apart, 20)
    box = trimesh.creation.box((0.2, 0.1, 0.05))
    inverted = box.copy()
    inverted.invert()
    np.testing.assert_array_equal(from_mesh(inverted, 6).nodes, from_mesh(box, 6).nodes)
    assert inverted.volume < 0  # the caller's mesh is left as it was


def test_a_shell_wound_inwards_outside_every_solid_is_refused():
    # An inward shell is a cavity only inside a solid. One that reaches outside (a bar with
    # flipped faces crossing another, a cavity poking through its box) was taken for one:
    # the crossing bars were cut to an arm, the box notched, with "raise resolution to keep
    # thin parts"
    bar, flipped = trimesh.creation.box((0.2, 0.05, 0.05)), trimesh.creation.box((0.05, 0.2, 0.05))
    flipped.invert()
    poking = trimesh.creation.box((0.1, 0.1, 0.1)).apply_translation((0.1, 0.0, 0.0))
    poking.invert()
    alone = trimesh.creation.box((0.1, 0.1, 0.1)).apply_translation((0.5, 0.0, 0.0))
    alone.invert()
    for other in (flipped, poking, alone):
        outer = bar if other is flipped else trimesh.creation.box((0.2, 0.2, 0.2))
        with pytest.raises(ValueError, match="a shell wound inwards .a cavity. reaches outside "
                           "every solid shell"):  # fmt: skip
            from_mesh(trimesh.util.concatenate([outer, other]), 10)


def test_from_mesh_warns_of_separate_bodies_and_of_units():
    two = [trimesh.creation.box((0.1, 0.1, 0.1)) for _ in range(2)]
    two[1].apply_translation((0.12, 0.0, 0.0))  # 2 cm apart
    with pytest.warns(UserWarning, match="the mesh has 2 separate bodies but its voxels form one"):
        from_mesh(trimesh.util.concatenate(two), 10)  # voxels of 2.2 cm: joined
    with pytest.warns(UserWarning, match="dropped 729 of 1458 voxels: the mesh has 2 separate"):
        from_mesh(trimesh.util.concatenate(two), 20)
    millimetres = trimesh.creation.box((200.0, 100.0, 50.0))
    with pytest.warns(UserWarning, match="the robot is 200 m long: units are metres"):
        from_mesh(millimetres, 4)
    robot = from_mesh(millimetres, 4, scale=0.001)
    assert np.ptp(robot.nodes, axis=0).max() == pytest.approx(0.2)
    # 5 mm and 5 m themselves are in range, silently (guards `<=` becoming `<`)
    for length in (0.005, 5.0):
        from_mesh(trimesh.creation.box((length, length / 2, length / 2)), 2)


def test_from_mesh_warns_when_thin_parts_change_the_volume():
    # a 1 mm plate filled whole voxels of 5 mm at the default resolution: five times the
    # mass, silently
    plate = trimesh.creation.box((0.1, 0.1, 0.001))
    with pytest.warns(UserWarning, match=r"the robot has 5 times the mesh's volume \(and mass\): "
                      r"at resolution 20 a voxel is 0.005 m wide"):  # fmt: skip
        robot = from_mesh(plate, 20)
    assert robot.volume == pytest.approx(5 * 0.1 * 0.1 * 0.001)
    rod = trimesh.creation.cylinder(radius=0.002, height=0.1)
    with pytest.warns(UserWarning, match="times the mesh's volume"):
        from_mesh(rod, 10)
    # a plate resolved by its voxels, and a coarse sphere (1.24 times), are silent
    assert from_mesh(trimesh.creation.box((0.1, 0.1, 0.005)), 20).volume == pytest.approx(5e-5)
    from_mesh(trimesh.creation.icosphere(2, 0.05), 6)
    # a box with one face wound against the others (trimesh's volume halves) is no thin part
    box = trimesh.creation.box((0.1, 0.05, 0.03))
    faces = box.faces.copy()
    faces[0] = faces[0][::-1]
    flipped = trimesh.Trimesh(box.vertices, faces, process=False)
    assert flipped.is_watertight and not flipped.is_winding_consistent
    assert from_mesh(flipped, 6).num_nodes == from_mesh(box, 6).num_nodes


def test_from_mesh_refuses_a_resolution_too_fine_to_mesh():
    # resolution 10**6 died in numpy's MemoryError ("Unable to allocate 1.04 EiB"), naming no
    # argument; 200 tested 4 million voxel centres against the surface for many minutes
    box = trimesh.creation.box((0.1, 0.05, 0.03))
    grid = r"1000000 x 500000 x 300000 = 150,000,000,000,000,000 voxels, over the 1,000,000 a"
    with pytest.raises(ValueError, match=rf"resolution 1000000 makes a grid of {grid}"):
        from_mesh(box, 10**6)
    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    with pytest.raises(ValueError, match=r"101 x 101 x 101 = 1,030,301 voxels.*use resolution "
                       r"<= 100 \(20 is the default\)"):  # fmt: skip
        from_mesh(cube, 101)
    assert from_mesh(box, 60).num_nodes > 10_000  # (a 60 x 30 x 18 grid is meshed)
    with pytest.raises(ValueError, match="resolution 1000000 makes a grid of 1000000 x "):
        make_robot("beam", resolution=10**6)  # the benchmark robots too (83 PiB asked for)
    # 10**20 voxels along a side wrapped int64 to a 1-voxel side, and meshed 8 nodes
    with pytest.raises(ValueError, match="resolution 100000000000000000000 makes a grid of "):
        from_mesh(box, 10**20)
    with pytest.raises(ValueError, match="resolution 100000000000000000000 makes a grid of "):
        make_robot("beam", resolution=10**20)


def test_degenerate_faces_do_not_make_a_mesh_open():
    box = trimesh.creation.box((0.2, 0.1, 0.05))
    faces = np.vstack([box.faces, [[0, 0, 1]]])  # a zero-area triangle
    broken = trimesh.Trimesh(box.vertices, faces, process=False)
    assert not broken.is_watertight
    assert from_mesh(broken, 6).num_nodes == from_mesh(box, 6).num_nodes


def _grid_axes(mesh, resolution):
    """The voxel centres' coordinates along x, y, z on the grid from_mesh places."""
    lo, hi = mesh.bounds
    pitch = float((hi - lo).max()) / resolution
    counts = np.maximum(np.round((hi - lo) / pitch), 1).astype(int)
    origin = 0.5 * (lo + hi) - 0.5 * pitch * counts
    return [origin[a] + pitch * (np.arange(counts[a]) + 0.5) for a in range(3)]


def test_the_column_fill_is_trimesh_s_contains(monkeypatch):
    # trimesh's contains (two rays per voxel centre) took a minute for a 20k-face sphere at
    # resolution 20; the fill counts crossings up each column instead, and must fill the
    # same voxels (cached robots and figures depend on them).
    from softrom_gym.robots.mesh_import import _inside

    rays = []
    contains = trimesh.Trimesh.contains

    def counted(self, points):
        rays.append(len(points))
        return contains(self, points)

    monkeypatch.setattr(trimesh.Trimesh, "contains", counted)
    turn = trimesh.transformations.random_rotation_matrix(np.random.default_rng(0).random(3))
    lying = trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0))
    cavity = trimesh.creation.box((0.1, 0.1, 0.1))
    cavity.invert()
    hollow = trimesh.util.concatenate([trimesh.creation.box((0.2, 0.2, 0.2)), cavity])
    spheres = [trimesh.creation.icosphere(2, 0.1), trimesh.creation.icosphere(2, 0.08)]
    spheres[1].apply_translation((0.15, 0.15, 0.0))
    meshes = {
        # columns along the faces' diagonals at even resolutions: each crossing counted once
        "cube": (trimesh.creation.box((0.1, 0.1, 0.1)), (4, 7, 8)),
        "turned box": (trimesh.creation.box((0.2, 0.1, 0.05)).apply_transform(turn), (6, 9)),
        "sphere": (trimesh.creation.icosphere(3, 0.1), (10, 13)),
        "capsule": (trimesh.creation.capsule(height=0.3, radius=0.08), (10,)),
        "torus": (trimesh.creation.torus(0.1, 0.04).apply_transform(lying), (12,)),
        "cone": (trimesh.creation.cone(0.05, 0.1), (7,)),  # a column through its apex
        "hollow box": (hollow, (10, 11)),
        "two spheres": (trimesh.util.concatenate(spheres), (12,)),
    }
    for name, (mesh, resolutions) in meshes.items():
        for resolution in resolutions:
            axes = _grid_axes(mesh, resolution)
            rays.clear()
            fast = _inside(mesh, axes)
            asked = sum(rays)
            centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            expected = contains(mesh, centres).reshape(fast.shape)
            assert np.array_equal(fast, expected), (name, resolution)
            assert expected.any()
            # contains decides only centres on the surface (or within 1e-6 of it), where its
            # answer is its own: the hollow box's cavity walls pass through centres at 10
            if name == "hollow box" and resolution == 10:
                assert 0 < asked < fast.size / 4
            elif name != "cone":  # (its apex and base centre are on a column at 7)
                assert asked == 0, (name, resolution)


def test_a_triangle_soup_is_closed_by_merging_its_vertices():
    # a Trimesh made with process=False from an STL's triangles (three own vertices each) was
    # "not watertight (36 boundary edges) ... e.g. trimesh.repair.fill_holes", which it is once
    # its coincident vertices are merged, and which fill_holes does not cure
    box = trimesh.creation.box((0.2, 0.1, 0.05))
    soup = trimesh.Trimesh(box.vertices[box.faces].reshape(-1, 3), np.arange(36).reshape(12, 3),
                           process=False)  # fmt: skip
    assert not soup.is_watertight
    assert from_mesh(soup, 6).num_nodes == from_mesh(box, 6).num_nodes


def test_duplicate_faces_and_edges_shared_by_bodies_are_told_from_holes():
    # Both were "not watertight (0 boundary edges) ... e.g. trimesh.repair.fill_holes": there
    # is no hole. A face listed twice carries nothing and is dropped; bodies touching along
    # an edge are named as such.
    box = trimesh.creation.box((0.2, 0.1, 0.05))
    twice = trimesh.Trimesh(box.vertices, np.vstack([box.faces, box.faces[:1]]), process=False)
    assert not twice.is_watertight
    assert from_mesh(twice, 6).num_nodes == from_mesh(box, 6).num_nodes
    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    touching = trimesh.util.concatenate([cube, cube.copy().apply_translation((0.1, 0.1, 0.0))])
    touching.merge_vertices()
    with pytest.raises(ValueError, match=r"mesh is not watertight \(1 edges shared by more than "
                       r"two faces: bodies touching along an edge"):  # fmt: skip
        from_mesh(touching, 10)
    with pytest.raises(ValueError, match=r"mesh is not watertight \(3 boundary edges\).*"
                       r"fill_holes"):  # fmt: skip
        from_mesh(trimesh.Trimesh(box.vertices, box.faces[1:], process=False), 6)


def test_from_mesh_names_a_flat_mesh_and_non_finite_vertices():
    # both were reported as "resolution 6 is too coarse", which no resolution cures
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 1]], process=False)
    assert flat.is_watertight
    with pytest.raises(ValueError, match="the mesh encloses no volume"):
        from_mesh(flat, 6)
    box = trimesh.creation.box((0.2, 0.1, 0.1))
    nan = trimesh.Trimesh(box.vertices.copy(), box.faces, process=False)
    nan.vertices[0, 0] = np.nan
    with pytest.raises(ValueError, match=r"1 vertices with non-finite coordinates \(NaN or inf\)"):
        from_mesh(nan, 6)
    ring = trimesh.creation.annulus(r_min=0.9, r_max=1.0, height=1.0)  # centres in the hole
    with pytest.raises(ValueError, match="resolution 2 is too coarse"):  # still said where true
        from_mesh(ring, 2)


def test_a_robot_names_tetrahedra_that_are_not_node_indices():
    # tets of 4.9 were truncated to node 4 silently; an index past the nodes made
    # robot.surface() an IndexError and an empty robot 'choose 1 <= M <= -6'
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]) * 0.05
    with pytest.raises(ValueError, match=r"tets must be node indices \(integers\), got 4.9 in "
                       r"tets\[1\]"):  # fmt: skip
        Robot("x", nodes, [[0, 1, 2, 3], [1, 2, 3, 4.9]])
    with pytest.raises(ValueError, match=r"tets\[1\] = \[1, 2, 3, 7\] has node index 7 out "
                       r"of range \[0, 5\)"):  # fmt: skip
        Robot("x", nodes, [[0, 1, 2, 3], [1, 2, 3, 7]])
    with pytest.raises(ValueError, match=r"tets\[0\] = \[-1, 1, 2, 3\] has node index -1 "):
        Robot("x", nodes, [[-1, 1, 2, 3]])
    with pytest.raises(ValueError, match="a robot needs at least one tetrahedron, got none"):
        Robot("x", np.zeros((0, 3)), np.zeros((0, 4)))
    with pytest.raises(ValueError, match=r"tets must be node indices \(integers\), got a bool"):
        Robot("x", nodes, np.ones((1, 4), dtype=bool))
    whole = Robot("x", nodes, np.array([[0, 1, 2, 3], [1, 2, 3, 4]], dtype=float))  # integral
    assert whole.tets.dtype == np.int64 and whole.tets.tolist() == [[0, 1, 2, 3], [1, 2, 3, 4]]


def test_a_robot_names_non_finite_or_complex_nodes_and_inverted_tetrahedra():
    # Found by building robots from bad arrays: NaN nodes gave volume nan, complex nodes lost
    # their imaginary part with a warning only, bool nodes were read as 0 / 1 m, and a
    # tetrahedron wound the wrong way gave a negative volume and mass; only fem_model()
    # refused them. A string material override was pybind11's argument listing.
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]) * 0.05
    tets = [[0, 1, 2, 3]]
    assert Robot("x", nodes, tets).volume == pytest.approx(0.05**3 / 6)
    bad = nodes.astype(float)
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"nodes\[2\] = \[0.0, nan, 0.0\] is not finite"):
        Robot("x", bad, tets)
    with pytest.raises(ValueError, match="nodes must be real numbers, got a complex128 array"):
        Robot("x", nodes + 0j, tets)
    with pytest.raises(ValueError, match="nodes must be real numbers, got a bool array"):
        Robot("x", nodes > 0, tets)
    with pytest.raises(ValueError, match=r"tets\[0\] = \[1, 0, 2, 3\] has non-positive rest "
                       r"volume -2.08333e-05"):  # fmt: skip
        Robot("x", nodes, [[1, 0, 2, 3]])
    with pytest.raises(TypeError, match="youngs_modulus must be a real number, got '1e4'"):
        Robot("x", nodes, tets).fem_model(youngs_modulus="1e4")


def test_robot_and_from_mesh_name_bad_shapes_resolutions_and_scales(tmp_path):
    nodes, tets = np.eye(4, 3), np.array([[0, 1, 2, 3]])
    with pytest.raises(ValueError, match=r"nodes has shape \(4, 2\), expected \(N, 3\)"):
        Robot("x", nodes[:, :2], tets)
    with pytest.raises(ValueError, match=r"tets has shape \(1, 3\), expected \(T, 4\)"):
        Robot("x", nodes, tets[:, :3])
    robot = ROBOTS["beam"](resolution=6)
    # a tetrahedron listed twice, in any vertex order: its mass counted twice and its faces
    # taken for inner ones (a review, session 54)
    twice = np.vstack([robot.tets, robot.tets[3][[1, 0, 3, 2]]])
    with pytest.raises(ValueError, match=rf"tets\[3\] and tets\[{robot.num_tets}\] are the "
                       "same tetrahedron"):  # fmt: skip
        Robot("x", robot.nodes, twice)
    with pytest.raises(ValueError, match=rf"positions has shape \(3, 3\), expected "
                       rf"\({robot.num_nodes}, 3\)"):  # fmt: skip
        robot.surface(np.zeros((3, 3)))
    with pytest.raises(TypeError, match=r"unknown material parameter\(s\) \['E'\]"):
        robot.fem_model(E=1e5)
    box = trimesh.creation.box((0.2, 0.1, 0.1))
    with pytest.raises(ValueError, match="resolution must be >= 2 voxels along the longest side, "
                       "got 1"):  # fmt: skip
        from_mesh(box, 1)
    for bad in (2.5, True):
        with pytest.raises(TypeError, match=f"resolution must be an integer, got {bad}"):
            from_mesh(box, bad)
    for scale in (0.0, -1.0, float("inf")):
        with pytest.raises(ValueError, match=f"scale must be > 0, got {scale}"):
            from_mesh(box, 4, scale=scale)
    cloud = tmp_path / "points.ply"
    trimesh.PointCloud(np.random.default_rng(0).random((10, 3))).export(cloud)
    with pytest.raises(ValueError, match="points.ply' holds no triangle mesh"):
        from_mesh(cloud, 4)


def test_voxels_to_tets_names_a_bad_pitch_or_origin():
    # Found by passing each a wrong value: a string pitch was numpy's "ufunc 'isfinite' not
    # supported", a NaN origin silently NaN nodes, a 2-number origin a broadcasting error.
    from softrom_gym.robots.voxel import voxels_to_tets

    occ = np.ones((2, 1, 1), dtype=bool)
    with pytest.raises(TypeError, match="pitch must be a real number, got '0.1'"):
        voxels_to_tets(occ, "0.1")
    for origin in ([np.nan, 0.0, 0.0], [0.0, 0.0]):
        with pytest.raises(ValueError, match="origin must be 3 finite numbers"):
            voxels_to_tets(occ, 0.1, origin=origin)
    nodes, _ = voxels_to_tets(occ, 0.1, origin=[1.0, 2.0, 3.0])
    np.testing.assert_allclose(nodes.min(axis=0), [1.0, 2.0, 3.0])
    np.testing.assert_allclose(nodes.max(axis=0), [1.2, 2.1, 3.1])
