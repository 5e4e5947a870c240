// The dense kernels of the cubature force and stiffness (reduced_elastic.cpp) and the contact
// solve's matrix-vector products (staggered_projection.cpp, fast solver), built for two
// instruction sets in one binary: the x86-64 baseline (SSE2), which every x86-64 machine runs, and
// x86-64-v3 (AVX2 + FMA), used where the CPU has it unless the environment variable
// SOFTROM_KERNELS=baseline asks for the baseline. The two sets compute the same sums and round
// differently (fused multiply-adds). Other compilers and architectures (arm64, clang, MSVC)
// build the plain loops for their own baseline. Measured in benchmarks/PROFILE.md (session 13).
#pragma once

#include <cstddef>

namespace softrom::kernels {

using Index = std::ptrdiff_t;

// The instruction set the kernels run with in this process: "x86-64-v3" or "baseline".
const char* instruction_set();

// out (width x width, column-major) gets the lower triangle of G^T X, for G and X of `rows` x
// `width`; the strictly upper triangle gets partial sums that are not G^T X's, as in
// gram_lower_add (zeroing it cost ~7 k instructions a call, a memset per column, and every
// caller reads the lower triangle only). (The primal friction system's J_l^T W J_l.)
void gram_lower(const double* g, const double* x, Index rows, Index width, double* out);

// Adds G^T X's lower triangle to out's, for G and X of `rows` x `width`, out as in
// gram_lower; the strictly upper triangle gets partial sums that are not G^T X's (callers
// read the lower triangle only). Calls over consecutive row ranges give out bit for bit what
// one call over all the rows would. (The reduced stiffness, a few elements' rows at a time,
// so each group's H G is still in L1 when the Gram product reads it.)
void gram_lower_add(const double* g, const double* x, Index rows, Index width, double* out);

// out (rows) = A x, for A of `rows` x `cols` in column-major order (an Eigen MatrixXd) and
// x of `cols`; any `rows`. (The contact solve's products with the candidates' normal rows, the
// loaded rows and L^-1, L^-T; NNLS's gradient G^T r on a kept G^T; the quasi-Newton's
// products with its inverse; the drag's and the damping's products.)
void cols_times(const double* a, Index rows, Index cols, const double* x, double* out);

// out (cols) = A^T x, for A of `rows` x `cols` in column-major order and x of `rows`: one dot
// product per column, in per-lane partial sums (fastest when rows is a multiple of 4). (The
// dot half of cols_dot_times, which the fast swimmer uses; on its own, for the tests.)
void cols_dot(const double* a, Index rows, Index cols, const double* x, double* out);

// out_x = A x and out_y = A y in one pass over A (column-major, `rows` x `cols`), the sums of
// two calls of cols_times (each entry one multiply-add chain over the columns in order). (The
// fast drag's surface positions and velocities, and the candidate test's N q and N v: one read
// of the rows for both.)
void cols_times_pair(const double* a, Index rows, Index cols, const double* x, const double* y,
                     double* out_x, double* out_y);

// dots (cols) = A^T x and out (rows) = A dots, for A of `rows` x `cols` in column-major order:
// the sums of cols_dot then cols_times, in one sweep over A when rows is a multiple of 4 up to
// 32. (GCC fuses cols_times' short forms below 20 rows differently, so there out may differ
// from its in the last bit; at the cross swimmer's 28 rows the bits are the same.) (The fast
// swimmer's potential: W^T g and W (W^T g), W the drag's factor.)
void cols_dot_times(const double* a, Index rows, Index cols, const double* x, double* dots,
                    double* out);

// For i < count: column i of out (leading dimension ld >= width) = w[3 i] a_(3 b_i) +
// w[3 i + 1] a_(3 b_i + 1) + w[3 i + 2] a_(3 b_i + 2), a_r the r-th row of the row-major a
// (`width` columns), b_i = blocks[i]; rows past width of out are left as they are. (The fast
// swimmer's drag factor: each advancing face's column U_t^T n from its three rows of U_t.)
void combine_row_triples(const double* a, Index width, const Index* blocks, const double* w,
                         Index count, double* out, Index ld);

// Solves L X = B in place for X, with L lower triangular (n x n, column-major, nonzero
// diagonal) and B n x nrhs stored row-major (row i of B contiguous: the memory of an Eigen
// MatrixXd J of nrhs x n is J^T in this layout). Forward substitution by rows, so the long
// dimension (the right-hand sides) is the vectorised one. (The contact solve's
// E^T = L^-1 J_n^T, n = 26 and ~64 right-hand sides on the quadruped: 0.08 M instructions
// per contact step fewer than Eigen's blocked triangular solve, by callgrind; also L^-1
// itself, whose products then give the pool's L^-1 J_t,i^T.)
void lower_solve_rows(const double* l, Index n, double* b, Index nrhs);

// Overwrites the lower triangle of the symmetric a (n x n, column-major, leading dimension
// lda >= n + 3) with its Cholesky factor L (A = L L^T; the strictly upper triangle is not read
// or written). Rows n, n + 1, n + 2 of every column are padding that the kernel reads and
// writes as if they were matrix rows: they must hold zeros on entry, and do on return.
// Returns false, with a partly overwritten a, when a pivot is not positive and finite. Each
// column is a register-resident update by the earlier ones (left-looking), vectorised over its
// rows; every entry is the sum of small::cholesky_upper (Cholesky-Crout) in its order, without
// fused multiply-adds, so the factor is that one's, transposed, to the bit. In a standalone
// harness (x86-64-v3) it took 0.54x the scalar loops' time at n = 26, 0.73x at 20 and 1.31x at 14
// (benchmarks/PROFILE.md, session 27). (The primal friction half's (M + 6)-square system,
// factored once per stagger.)
bool cholesky_lower(double* a, Index n, Index lda);

// One cubature element's rows of H G for the stable Neo-Hookean material (material.h), without
// forming H = w dP/dF: out (9 x width) = H g, with coef = [vec cof F (9), w lambda vec cof F
// (9), w s vec F (9), w mu], s = lambda (det F - 1) - mu, and g the element's 9 rows of G.
// H = w (mu I + lambda vec cof F vec cof F^T + s d vec cof F / d vec F); the last term applied
// as the derivative of the cofactor's cross products (63 multiply-adds per column, not 81).
void snh_element_hg(const double* coef, const double* g, Index width, double* out);

// G interleaved by elements: the cubature elements in groups of four (the last group padded with
// zero rows), each group a block of 36 x width doubles, gi[36 (g width + j) + 4 i + l] =
// G[9 (4 g + l) + i, j], i.e. for each of G's columns the group's nine rows as 4-lane packets,
// one element per lane. Both products of a force evaluation read it once (snh_force).

// The stable Neo-Hookean cubature energy and force in one pass over the interleaved G of
// `groups` groups: returns sum_k w_k psi(F_k) and sets gtp (width) = G^T P, P's nine entries per
// element w_k P(F_k), F_k = I + G_k q. w has 4 groups entries (0 on the padding), `lanes` is
// 4 width doubles of scratch. (The reduced force's evaluation, the quasi-Newton's line search.)
double snh_force(const double* gi, Index groups, Index width, const double* q, const double* w,
                 double mu, double lambda, double* lanes, double* gtp);

// f_minus_i (9 count, element-major) = G q for the first `count` elements of the interleaved G
// (vec F_k - vec I; each entry one multiply-add chain over q's entries in order, as in
// snh_force). (The stiffness's deformation gradients.)
void interleaved_deformation(const double* gi, Index count, Index width, const double* q,
                             double* f_minus_i);

}  // namespace softrom::kernels
