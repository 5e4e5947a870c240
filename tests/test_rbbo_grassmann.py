"""Points of Gr(M, C) and the projection distance (rbbo.grassmann)."""

import numpy as np
import pytest
from scipy.stats import ortho_group

from rbbo import grassmann as gr


def test_distance_matches_projector_norm(rng):
    a, b = gr.random_points(9, 3, 2, rng)
    direct = np.linalg.norm(a @ a.T - b @ b.T)
    assert gr.projection_distance(a, b) == pytest.approx(direct, rel=1e-12)
    sq = gr.projection_sq_distances(np.stack([a, b]))
    np.testing.assert_allclose(sq, [[0, direct**2], [direct**2, 0]], atol=1e-12)


def test_distance_is_invariant_under_rotation_of_columns(rng):
    a, b = gr.random_points(8, 3, 2, rng)
    q = ortho_group.rvs(3, random_state=1)
    assert gr.projection_distance(a @ q, b) == pytest.approx(gr.projection_distance(a, b))
    assert gr.projection_distance(a, a @ q) == pytest.approx(0.0, abs=1e-7)


@pytest.mark.parametrize("eps", [1e-4, 1e-7, 1e-10, 1e-13])
def test_distance_of_near_identical_subspaces_matches_principal_angles(rng, eps):
    from scipy.linalg import subspace_angles

    a = gr.random_points(20, 3, rng=rng)
    g = rng.standard_normal(a.shape)
    g -= a @ (a.T @ g)
    u, _, vt = np.linalg.svd(a + eps * g / np.linalg.norm(g), full_matrices=False)
    b = u @ vt
    expected = np.sqrt(2.0) * np.linalg.norm(np.sin(subspace_angles(a, b)))
    assert gr.projection_distance(a, b) == pytest.approx(expected, rel=1e-6)
    assert gr.projection_distance(a, b) == gr.projection_distance(b, a)
    assert gr.projection_distance(a, a @ ortho_group.rvs(3, random_state=2)) < 1e-14


def test_orthogonal_subspaces_are_sqrt_2c_apart():
    e = np.eye(6)
    assert gr.projection_distance(e[:, :3], e[:, 3:]) == pytest.approx(np.sqrt(6.0))


def test_random_points_are_orthonormal_and_spread(rng):
    pts = gr.random_points(10, 2, 200, rng)
    for p in pts[:5]:
        gr.validate_basis(p, 10, 2)
    # E ||B^T U||_F^2 = C^2 / M for a uniform subspace against a fixed one
    u = np.eye(10)[:, :2]
    mean_overlap = np.mean(np.sum((pts.transpose(0, 2, 1) @ u) ** 2, axis=(1, 2)))
    assert mean_overlap == pytest.approx(4 / 10, abs=0.06)
    assert gr.random_points(5, 2, 0, rng).shape == (0, 5, 2)
    assert gr.flatten(gr.random_points(5, 2, 0, rng)).shape == (0, 10)  # an empty X
    for n in (2.5, -1, True):
        with pytest.raises(ValueError, match="n must be an integer >= 0"):
            gr.random_points(5, 2, n, rng)


def test_canonical_depends_on_span_only(rng):
    b = gr.random_points(7, 3, rng=rng)
    q = ortho_group.rvs(3, random_state=2)
    c1, c2 = gr.canonical(b), gr.canonical(b @ q)
    np.testing.assert_allclose(c1, c2, atol=1e-12)
    np.testing.assert_allclose(c1 @ c1.T, b @ b.T, atol=1e-12)
    np.testing.assert_array_equal(gr.canonical(gr.identity_basis(7, 3)), np.eye(7)[:, :3])
    # almost every subspace: the leading C x C block is lower triangular with a positive
    # diagonal (the first C rows are the pivots)
    np.testing.assert_allclose(np.triu(c1[:3], 1), 0.0, atol=1e-15)
    assert np.all(np.diag(c1) > 0)


def test_canonical_depends_on_span_only_when_the_leading_block_is_singular(rng):
    """Subspaces whose first C rows do not span R^C, e.g. a selection of modes (e_4, e_5, e_6)
    or any subspace of the later modes: a QR of B_c^T without pivoting depends on Q there."""
    q = ortho_group.rvs(3, random_state=5)
    modes_456 = np.eye(9)[:, 3:6]
    np.testing.assert_allclose(gr.canonical(modes_456 @ q), modes_456, atol=1e-14)
    later = np.zeros((9, 3))
    later[4:] = gr.random_points(5, 3, rng=rng)  # span inside the last five modes
    mixed = np.zeros((9, 3))
    mixed[[0, 3, 4, 6, 7, 8]] = gr.random_points(6, 3, rng=rng)  # rows 1, 2, 5 zero
    mixed[2] = 0.0
    for b in (later, mixed, gr.orthonormalize(np.eye(9)[:, [0, 1, 4]] + np.eye(9)[:, [0, 3, 4]])):
        c1, c2 = gr.canonical(b), gr.canonical(b @ q)
        np.testing.assert_allclose(c1, c2, atol=1e-12)
        np.testing.assert_allclose(c1 @ c1.T, b @ b.T, atol=1e-12)


def test_flatten_roundtrip(rng):
    pts = gr.random_points(5, 2, 4, rng)
    x = gr.flatten(pts)
    assert x.shape == (4, 10)
    np.testing.assert_array_equal(gr.unflatten(np.column_stack([x, np.ones(4)]), 5, 2), pts)


def test_orthonormalize_keeps_span(rng):
    a = rng.standard_normal((6, 2))
    q = gr.orthonormalize(a)
    gr.validate_basis(q, 6, 2)
    np.testing.assert_allclose(q @ q.T @ a, a, atol=1e-12)


def test_dimension():
    assert gr.dimension(20, 3) == 51


@pytest.mark.parametrize(
    ("b", "kwargs", "match"),
    [
        (np.ones(3), {}, r"2-D \(M, C\) array, got shape \(3,\)"),
        (np.eye(4)[:, :2], {"sim_dim": 5}, r"shape \(4, 2\), expected .* = \(5, C\)"),
        (np.eye(3), {"control_dim": 2}, r"shape \(3, 3\), expected"),
        (2 * np.eye(4)[:, :2], {}, r"not orthonormal: max \|B_c\^T B_c - I\| = 3"),
        (np.full((3, 1), np.nan), {}, "non-finite values"),
        (np.eye(2, 3), {}, "control_dim = 3 exceeds sim_dim = 2"),
    ],
)
def test_validate_basis_errors(b, kwargs, match):
    with pytest.raises(ValueError, match=match):
        gr.validate_basis(b, **kwargs)


def test_bad_dims_and_rank():
    with pytest.raises(ValueError, match="control_dim must be a positive integer, got 0"):
        gr.random_points(4, 0)
    with pytest.raises(ValueError, match="full-rank"):
        gr.orthonormalize(np.ones((4, 2)))
    with pytest.raises(TypeError, match="real \\(M, C\\) array"):
        gr.validate_basis([["a", "b"]])
    # not read as its real part (numpy would only warn)
    with pytest.raises(TypeError, match="B_c must be real, got a complex128 array"):
        gr.validate_basis(np.eye(4)[:, :2] + 1e-3j)
    with pytest.raises(TypeError, match="B_i must be real, got a complex64 array"):
        gr.projection_distance(np.eye(4, 2, dtype=np.complex64), np.eye(4)[:, :2])


def test_validate_basis_refuses_unit_columns_that_are_not_orthogonal():
    """Unit columns 60 degrees apart: each column norm is 1, B^T B is not I."""
    b = np.zeros((4, 2))
    b[0, 0] = 1.0
    b[:2, 1] = [0.5, np.sqrt(0.75)]
    with pytest.raises(ValueError, match=r"not orthonormal: max \|B_c\^T B_c - I\| = 0.5"):
        gr.validate_basis(b)


def test_a_full_grassmannian_gr_m_m_is_a_point():
    """C = M is allowed (one subspace, dimension 0); only C > M is refused."""
    assert gr.dimension(4, 4) == 0
    gr.validate_basis(np.eye(4))
    assert gr.projection_distance(np.eye(4), ortho_group.rvs(4, random_state=0)) < 1e-14


def test_orthonormalize_takes_a_square_matrix_and_gives_a_positive_diagonal_r(rng):
    """The documented QR with R_ii > 0, so the result is a function of the matrix (LAPACK's
    sign convention is not part of it), square matrices included."""
    for shape in ((6, 2), (4, 4)):
        a = rng.standard_normal(shape)
        q = gr.orthonormalize(a)
        r = q.T @ a
        np.testing.assert_allclose(q @ r, a, atol=1e-12)
        np.testing.assert_allclose(np.tril(r, -1), 0.0, atol=1e-12)
        assert np.all(np.diag(r) > 0)


def test_random_points_are_haar_on_the_stiefel_manifold_not_only_their_spans(rng):
    """The documented sign fix: without it LAPACK's QR gives every first column a negative
    first entry (Q = G R^-1 with R_11 = -sign(g_11) |g_1|)."""
    pts = gr.random_points(6, 2, 400, rng)
    for entry in (pts[:, 0, 0], pts[:, 1, 1]):
        assert 0.4 < np.mean(entry > 0) < 0.6


def test_projection_sq_distances_are_clipped_at_zero(rng):
    """2 C - 2 ||B_i^T B_j||_F^2 rounds to about -4e-15 on the diagonal; the documented clip
    keeps every squared distance a square (its sqrt no NaN)."""
    sq = gr.projection_sq_distances(gr.random_points(7, 2, 40, rng))
    assert sq.min() >= 0.0
    assert np.all(np.isfinite(np.sqrt(sq)))


def test_projection_distance_names_bases_of_different_shapes(rng):
    a = gr.random_points(6, 2, rng=rng)
    with pytest.raises(ValueError, match=r"B_j has shape \(6, 3\), expected \(sim_dim, "
                                         r"control_dim\) = \(6, 2\)"):  # fmt: skip
        gr.projection_distance(a, gr.random_points(6, 3, rng=rng))


def test_canonical_does_not_take_a_row_in_the_span_of_earlier_ones_for_a_pivot():
    """Rows 0 and 1 parallel: after B -> B U row 1's residual against row 0 is round-off, not
    zero; a pivot made of it points anywhere, and the representative with it."""
    b = np.zeros((5, 2))
    b[:2, 0] = np.array([1.0, 3.0]) / np.sqrt(10.0)
    b[3, 1] = 1.0
    expected = gr.canonical(b)
    np.testing.assert_allclose(expected @ expected.T, b @ b.T, atol=1e-15)
    for seed in range(20):
        q = ortho_group.rvs(2, random_state=seed)
        np.testing.assert_allclose(gr.canonical(b @ q), expected, atol=1e-12)


def test_orthonormalize_names_a_matrix_without_columns():
    """C = 0 reached numpy's "zero-size array to reduction operation minimum"."""
    for shape in ((5, 0), (0, 0)):
        with pytest.raises(ValueError, match=rf"1 <= C <= M, got shape \({shape[0]}, 0\)"):
            gr.orthonormalize(np.zeros(shape))


def test_canonical_is_orthonormal_when_a_pivot_row_is_nearly_in_the_span_of_earlier_ones(rng):
    """The docstring's "Gram-Schmidt twice: orthogonal to working precision": rows 0 and 1
    of B_c nearly parallel (row 1's residual ~1e-7, still a pivot) leave one classical
    Gram-Schmidt pass ~1e-8 from orthogonal (u / 1e-7); the representative B_c Q is then as
    far from orthonormal, and no longer as orthonormal as B_c (~1e-16)."""
    for seed in range(20):
        g = rng.standard_normal((7, 3))
        g[1] = g[0] + 1e-7 * rng.standard_normal(3)
        b = gr.orthonormalize(g) @ ortho_group.rvs(3, random_state=seed)
        assert np.abs(b.T @ b - np.eye(3)).max() < 1e-14
        c = gr.canonical(b)
        np.testing.assert_allclose(c.T @ c, np.eye(3), atol=1e-13)
        np.testing.assert_allclose(c @ c.T, b @ b.T, atol=1e-13)  # the same span


def test_random_points_columns_have_independent_signs(rng):
    """Haar on the Stiefel manifold: B and B diag(+-1) are equally likely, for each column
    on its own. The existing test checks the signs of B_00 and B_11 one at a time; a sign fix
    that flips every column by the sign of R_11 (instead of each by its own R_jj) passes it,
    but couples the columns: B_00 B_11 > 0 in ~92 % of draws."""
    pts = gr.random_points(6, 2, 2000, rng)
    assert 0.45 < np.mean(pts[:, 0, 0] * pts[:, 1, 1] > 0) < 0.55
    assert 0.45 < np.mean(np.linalg.det(pts[:, :2, :]) > 0) < 0.55
