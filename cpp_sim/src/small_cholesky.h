// Cholesky factorisation and solve for the contact solve's small dense systems (fast solver
// only): the friction half's 2 n x 2 n dual system, factored once per stagger, and the loaded
// set's normal block D_nn, once per set (n ~ 7 loaded nodes on a walker); and the triangular
// solves of the least-distance programme's growing factor (nnls_cholesky); and an LU solve for
// the held-set Newton step's unsymmetric 2 n x 2 n system.
//
// Eigen's dynamic-size LLT is blocked for large matrices: at these sizes its set-up costs more
// than the arithmetic (callgrind on the quadruped: ~9 k instructions to factor a 14 x 14
// matrix, whose work is ~460 multiply-adds). These are the textbook loops, for
// column-major storage (an Eigen MatrixXd's memory).
#pragma once

#include <cmath>
#include <cstddef>
#include <utility>

namespace softrom::small {

using Index = std::ptrdiff_t;

// Overwrites the upper triangle of the symmetric a (n x n, column-major, leading dimension
// lda) with its Cholesky factor U (A = U^T U; the strictly lower triangle is not read or
// written). Returns false, with a partly overwritten a, when a pivot is not positive and
// finite (A not numerically positive definite). Column j of U above the diagonal is row j of
// L = U^T, contiguous, so every entry is one dot product of two contiguous columns
// (Cholesky-Crout). At these sizes a scalar dot product costs fewer instructions than short
// vectorised updates: per factorisation of the quadruped's dual systems (callgrind), Eigen's
// LLT ~9 k instructions, a right-looking column loop ~8.7 k, this ~3.9 k.
// The entries are formed row by row of U: the dot products of one row (one per later column)
// are independent, so the core overlaps their multiply-add chains, where column by column
// each entry waited for the one above it. Every entry is the same sum in the same order as
// column by column, so the factor is the same to the bit; in a standalone harness (x86-64-v3)
// it took a third of the time at n = 10-26 (14 x 14: 883 -> 299 ns).
inline bool cholesky_upper(double* a, Index n, Index lda) {
  for (Index i = 0; i < n; ++i) {
    double* ci = a + i * lda;
    double d = ci[i];
    for (Index k = 0; k < i; ++k) d -= ci[k] * ci[k];
    if (!(d > 0.0) || !std::isfinite(d)) return false;
    const double uii = std::sqrt(d);
    ci[i] = uii;
    for (Index j = i + 1; j < n; ++j) {
      double* cj = a + j * lda;
      double s = cj[i];
      for (Index k = 0; k < i; ++k) s -= ci[k] * cj[k];
      cj[i] = s / uii;
    }
  }
  return true;
}

// b <- U^-T b for an upper triangular U (n x n, column-major, leading dimension lda), by
// updates along U's rows: b_j -= u_ij x_i as soon as x_i is known, in the order of the
// dot-product form's sum (the same bits), but with the later entries' chains independent
// (26 x 26 in the harness above: 262 -> 207 ns).
inline void upper_transpose_solve(const double* u, Index n, Index lda, double* b) {
  for (Index i = 0; i < n; ++i) {
    const double x = b[i] / u[i + i * lda];
    b[i] = x;
    for (Index j = i + 1; j < n; ++j) b[j] -= u[i + j * lda] * x;
  }
}

// b <- U^-1 b for an upper triangular U, column by column.
inline void upper_solve(const double* u, Index n, Index lda, double* b) {
  for (Index i = n - 1; i >= 0; --i) {
    const double* ci = u + i * lda;
    const double x = b[i] / ci[i];
    b[i] = x;
    for (Index k = 0; k < i; ++k) b[k] -= x * ci[k];
  }
}

// U^T U + x x^T = U'^T U' in place (U upper, n x n, column-major, leading dimension lda), by
// Givens rotations; x (n) is overwritten.
// (Two divisions per row, 1 / u_kk and 1 / c, each multiplied along the row instead of a
// division per entry.)
inline void cholesky_upper_update(double* u, Index n, Index lda, double* x) {
  for (Index k = 0; k < n; ++k) {
    const double ukk = u[k + k * lda];
    const double r = std::sqrt(ukk * ukk + x[k] * x[k]);
    const double inv_ukk = 1.0 / ukk;
    const double c = r * inv_ukk, s = x[k] * inv_ukk, inv_c = ukk / r;
    u[k + k * lda] = r;
    for (Index j = k + 1; j < n; ++j) {
      double& ukj = u[k + j * lda];
      ukj = (ukj + s * x[j]) * inv_c;
      x[j] = c * x[j] - s * ukj;
    }
  }
}

// U^T U - x x^T = U'^T U' in place, by hyperbolic rotations; x is overwritten. Returns false,
// with U partly overwritten, when a pivot's square would fall to `rel` times its old value or
// below (the difference not numerically positive definite).
inline bool cholesky_upper_downdate(double* u, Index n, Index lda, double* x, double rel) {
  for (Index k = 0; k < n; ++k) {
    const double ukk = u[k + k * lda];
    const double r2 = ukk * ukk - x[k] * x[k];
    if (!(r2 > rel * ukk * ukk) || !std::isfinite(r2)) return false;
    const double r = std::sqrt(r2);
    const double inv_ukk = 1.0 / ukk;
    const double c = r * inv_ukk, s = x[k] * inv_ukk, inv_c = ukk / r;
    u[k + k * lda] = r;
    for (Index j = k + 1; j < n; ++j) {
      double& ukj = u[k + j * lda];
      ukj = (ukj - s * x[j]) * inv_c;
      x[j] = c * x[j] - s * ukj;
    }
  }
  return true;
}

// b <- (U^T U)^-1 b, for U from cholesky_upper.
inline void cholesky_upper_solve(const double* u, Index n, Index lda, double* b) {
  upper_transpose_solve(u, n, lda, b);
  upper_solve(u, n, lda, b);
}

// b <- (L L^T)^-1 b, for L lower triangular (n x n, column-major, leading dimension lda; from
// kernels::cholesky_lower). L = U^T for the U of cholesky_upper, and the two substitutions are
// cholesky_upper_solve's, entry for entry, so the answer is its answer to the bit: forward
// along L's columns, then backward by updates along L's rows (strided, but independent, where
// the dot products along its columns would be one chain).
inline void cholesky_lower_solve(const double* l, Index n, Index lda, double* b) {
  for (Index i = 0; i < n; ++i) {
    const double* ci = l + i * lda;
    const double x = b[i] / ci[i];
    b[i] = x;
    for (Index j = i + 1; j < n; ++j) b[j] -= ci[j] * x;
  }
  for (Index i = n - 1; i >= 0; --i) {
    const double x = b[i] / l[i + i * lda];
    b[i] = x;
    for (Index k = 0; k < i; ++k) b[k] -= x * l[i + k * lda];
  }
}

// Solves A x = b in place (x holds b on entry), for a general a (n x n, column-major, leading
// dimension n, overwritten by its LU factors with partial pivoting). Returns false on a zero
// or non-finite pivot.
inline bool lu_solve(double* a, Index n, double* x) {
  for (Index c = 0; c < n; ++c) {
    Index p = c;
    double best = std::abs(a[c + c * n]);
    for (Index r = c + 1; r < n; ++r)
      if (std::abs(a[r + c * n]) > best) {
        best = std::abs(a[r + c * n]);
        p = r;
      }
    if (!(best > 0.0) || !std::isfinite(best)) return false;
    if (p != c) {
      for (Index j = 0; j < n; ++j) std::swap(a[c + j * n], a[p + j * n]);
      std::swap(x[c], x[p]);
    }
    const double inv = 1.0 / a[c + c * n];
    for (Index r = c + 1; r < n; ++r) a[r + c * n] *= inv;
    for (Index j = c + 1; j < n; ++j) {
      const double f = a[c + j * n];
      for (Index r = c + 1; r < n; ++r) a[r + j * n] -= a[r + c * n] * f;
    }
    for (Index r = c + 1; r < n; ++r) x[r] -= a[r + c * n] * x[c];
  }
  for (Index c = n - 1; c >= 0; --c) {
    x[c] /= a[c + c * n];
    for (Index r = 0; r < c; ++r) x[r] -= a[r + c * n] * x[c];
  }
  return true;
}

}  // namespace softrom::small
