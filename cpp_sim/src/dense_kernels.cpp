// See dense_kernels.h. The loops are written so that the compiler vectorises them without
// reassociating sums (no -ffast-math): the long dimension is the contiguous one, and the
// reductions keep explicit per-lane partial sums. Each body is compiled twice, for the
// baseline and (GCC on x86-64) for x86-64-v3, and a table of function pointers picks one
// set on first use. (GCC's target_clones would pick by itself, but could not be told to use
// the baseline on a machine with AVX2, which the tests and SOFTROM_KERNELS=baseline need.)
#include "dense_kernels.h"

#include <cmath>
#include <cstdlib>
#include <cstring>

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12
#define SOFTROM_KERNEL_DISPATCH 1
#define SOFTROM_INLINE __attribute__((always_inline)) inline
#else
#define SOFTROM_KERNEL_DISPATCH 0
#define SOFTROM_INLINE inline
#endif

// "The iterations of the next loop are independent": GCC otherwise versions a loop with many
// input and output streams for aliasing the __restrict pointers rule out, and with more
// streams than its run-time alias checks allow (snh_element_hg: 9 in, 9 out) leaves it scalar.
#if defined(__GNUC__) && !defined(__clang__)
#define SOFTROM_IVDEP _Pragma("GCC ivdep")
#else
#define SOFTROM_IVDEP
#endif

namespace softrom::kernels {

namespace {

// A 4-column, IB-row tile of G^T X over rows [r0, r1): its 4 x IB sums stay in registers (8
// AVX2 registers for IB = 8) while the rows stream past, each row adding an outer product.
template <int IB>
SOFTROM_INLINE void gram_tile(const double* __restrict g, const double* __restrict x, Index r0,
                              Index r1, Index width, Index i0, Index j0, double* __restrict out) {
  double acc[4][IB];
  for (int t = 0; t < 4; ++t)
    for (int s = 0; s < IB; ++s) acc[t][s] = out[i0 + s + (j0 + t) * width];
  for (Index r = r0; r < r1; ++r) {
    const double* gr = g + r * width + i0;
    const double* xr = x + r * width + j0;
    for (int t = 0; t < 4; ++t) {
      const double b = xr[t];
      for (int s = 0; s < IB; ++s) acc[t][s] += b * gr[s];
    }
  }
  for (int t = 0; t < 4; ++t)
    for (int s = 0; s < IB; ++s) out[i0 + s + (j0 + t) * width] = acc[t][s];
}

// The same tile for the x86-64-v3 kernels, on GCC's 4-lane vectors: the IB rows as IB / 4
// vectors, each row's 4 values of X broadcast. Written with plain arrays (gram_tile), GCC
// kept the sums in reversed lanes and spent the tile's start and end on shuffles and stack
// spills; in a standalone harness of the quadruped's Gram (139 elements, width 20) this form
// took 17 us against 22.6 us, with the same sums in the same order (the same bits). (The
// baseline keeps gram_tile: 4-lane vectors lowered to SSE2 ran 9x slower there.)
using Lanes4 = double __attribute__((vector_size(32), aligned(8), may_alias));
template <int IB>
SOFTROM_INLINE void gram_tile_lanes(const double* __restrict g, const double* __restrict x,
                                    Index r0, Index r1, Index width, Index i0, Index j0,
                                    double* __restrict out) {
  constexpr int kVectors = IB / 4;
  Lanes4 acc[4][kVectors];
  for (int t = 0; t < 4; ++t)
    for (int v = 0; v < kVectors; ++v)
      acc[t][v] = *reinterpret_cast<const Lanes4*>(out + i0 + 4 * v + (j0 + t) * width);
  for (Index r = r0; r < r1; ++r) {
    const double* gr = g + r * width + i0;
    const double* xr = x + r * width + j0;
    Lanes4 gv[kVectors];
    for (int v = 0; v < kVectors; ++v) gv[v] = *reinterpret_cast<const Lanes4*>(gr + 4 * v);
    for (int t = 0; t < 4; ++t) {
      const double b = xr[t];
      for (int v = 0; v < kVectors; ++v) acc[t][v] += b * gv[v];
    }
  }
  for (int t = 0; t < 4; ++t)
    for (int v = 0; v < kVectors; ++v)
      *reinterpret_cast<Lanes4*>(out + i0 + 4 * v + (j0 + t) * width) = acc[t][v];
}

// Adds the rows' outer products to `out` tile by tile (width a multiple of 4). Every entry on
// or below the diagonal belongs to one tile and gets its rows' products in row order, so
// splitting the rows into consecutive calls, or the columns into other tiles, changes no bit
// of the sum.
template <bool kLanes>
SOFTROM_INLINE void gram_lower_add_body(const double* __restrict g, const double* __restrict x,
                                        Index rows, Index width, double* __restrict out) {
  // Rows in chunks whose slices of G and X stay in L1 while every tile passes over them.
  constexpr Index kChunk = 48;
  for (Index r0 = 0; r0 < rows; r0 += kChunk) {
    const Index r1 = r0 + kChunk < rows ? r0 + kChunk : rows;
    for (Index j0 = 0; j0 < width; j0 += 4) {
      // 8-row tiles from the diagonal block down, and a 4-row one at the end (the diagonal
      // block's entries above the diagonal are computed too, and are not the sum's). Starting
      // at the diagonal block rather than at the last multiple of 8 above it computes no block
      // above it: 11 % fewer instructions on the stiffness's 28-wide Gram in a standalone
      // harness. 12-row tiles, which need all 16 AVX2 registers, cost 15 % more than 8-row
      // ones there (benchmarks/PROFILE.md, session 18).
      Index i0 = j0;
      if constexpr (kLanes) {
        for (; i0 + 8 <= width; i0 += 8) gram_tile_lanes<8>(g, x, r0, r1, width, i0, j0, out);
        if (i0 < width) gram_tile_lanes<4>(g, x, r0, r1, width, i0, j0, out);
      } else {
        for (; i0 + 8 <= width; i0 += 8) gram_tile<8>(g, x, r0, r1, width, i0, j0, out);
        if (i0 < width) gram_tile<4>(g, x, r0, r1, width, i0, j0, out);
      }
    }
  }
}

template <bool kLanes>
SOFTROM_INLINE void gram_lower_body(const double* __restrict g, const double* __restrict x,
                                    Index rows, Index width, double* __restrict out) {
  for (Index i = 0; i < width * width; ++i) out[i] = 0.0;
  gram_lower_add_body<kLanes>(g, x, rows, width, out);
}

// out = A x for A of `rows` x `cols` (column-major, 4 N - 4 < rows <= 4 N, rows >= 4): the
// 4 N sums stay in registers while the columns stream past, each adding one broadcast times
// one column. Every column but the last is read as 4 N rows: the up to three rows past its end
// are the next column's first ones, summed into lanes that are dropped (reading them keeps
// the loop free of a scalar tail, which measured slower than the products it saved).
template <int N>
SOFTROM_INLINE void cols_times_short(const double* __restrict a, Index rows, Index cols,
                                     const double* __restrict x, double* __restrict out) {
  double acc[4 * N];
  for (int r = 0; r < 4 * N; ++r) acc[r] = 0.0;
  for (Index c = 0; c + 1 < cols; ++c) {
    const double xc = x[c];
    const double* __restrict ac = a + c * rows;
    for (int r = 0; r < 4 * N; ++r) acc[r] += xc * ac[r];
  }
  // The last column, and the stores, touch only the last packet's lanes inside the matrix
  // (r < rows); the lanes' indices stay constants, so acc stays in registers.
  if (cols > 0) {
    const double xc = x[cols - 1];
    const double* __restrict ac = a + (cols - 1) * rows;
    for (int r = 0; r < 4 * N - 4; ++r) acc[r] += xc * ac[r];
    for (int r = 4 * N - 4; r < 4 * N; ++r)
      if (r < rows) acc[r] += xc * ac[r];
  }
  for (int r = 0; r < 4 * N - 4; ++r) out[r] = acc[r];
  for (int r = 4 * N - 4; r < 4 * N; ++r)
    if (r < rows) out[r] = acc[r];
}

// K columns [c, c + K) of a tall A added to out in one pass over it (the first pass writes
// out instead: the same sums as adding to zeros, without a pass to clear it).
template <int K, bool First = false>
SOFTROM_INLINE void cols_times_pass(const double* __restrict a, Index rows, Index c,
                                    const double* __restrict x, double* __restrict out) {
  double xs[K];
  for (int t = 0; t < K; ++t) xs[t] = x[c + t];
  const double* __restrict a0 = a + c * rows;
  for (Index r = 0; r < rows; ++r) {
    // (From a literal zero, not xs[0] a: GCC may fuse either product of a sum of two, and
    // this keeps the order of the multiply-adds, so the sums are those of a cleared out.)
    double o = First ? 0.0 : out[r];
    for (int t = 0; t < K; ++t) o += xs[t] * a0[t * rows + r];
    out[r] = o;
  }
}

// Short outputs (4 <= rows <= 32: the contact solve's products with L^-1 and L^-T and the
// loaded rows, the quasi-Newton's inverse, the damping's K_0, the drag's padded factor) keep
// out in registers over all the columns; tall ones (the candidates' normal rows, NNLS's G^T r)
// pass over out once per eight columns.
// Each out[r] is the sum over the columns in order (one multiply-add chain) in every path.
SOFTROM_INLINE void cols_times_body(const double* __restrict a, Index rows, Index cols,
                                    const double* __restrict x, double* __restrict out) {
  if (rows >= 4 && rows <= 32) {
    switch ((rows + 3) / 4) {
      case 8: cols_times_short<8>(a, rows, cols, x, out); return;
      case 7: cols_times_short<7>(a, rows, cols, x, out); return;
      case 6: cols_times_short<6>(a, rows, cols, x, out); return;
      case 5: cols_times_short<5>(a, rows, cols, x, out); return;
      case 4: cols_times_short<4>(a, rows, cols, x, out); return;
      case 3: cols_times_short<3>(a, rows, cols, x, out); return;
      case 2: cols_times_short<2>(a, rows, cols, x, out); return;
      default: cols_times_short<1>(a, rows, cols, x, out); return;  // rows = 4
    }
  }
  if (cols < 8) {
    for (Index r = 0; r < rows; ++r) out[r] = 0.0;
  } else {
    cols_times_pass<8, true>(a, rows, 0, x, out);
  }
  Index c = cols < 8 ? 0 : 8;
  for (; c + 8 <= cols; c += 8) cols_times_pass<8>(a, rows, c, x, out);
  switch (cols - c) {
    case 7: cols_times_pass<7>(a, rows, c, x, out); break;
    case 6: cols_times_pass<6>(a, rows, c, x, out); break;
    case 5: cols_times_pass<5>(a, rows, c, x, out); break;
    case 4: cols_times_pass<4>(a, rows, c, x, out); break;
    case 3: cols_times_pass<3>(a, rows, c, x, out); break;
    case 2: cols_times_pass<2>(a, rows, c, x, out); break;
    case 1: cols_times_pass<1>(a, rows, c, x, out); break;
    default: break;
  }
}

// out = A^T x: each output the dot product of one column with x. Four columns at a time, each
// with four per-lane partial sums over the rows in packets of four (the rows past the last
// whole packet go into the first lanes), combined as (s0 + s1) + (s2 + s3). Written with
// GCC's vector extension: as a plain loop, GCC vectorises the rows as in-order reductions (a
// shuffle per product, slower than scalar code). The plain loop computes the same sums for
// other compilers.
#if defined(__GNUC__) && !defined(__clang__)
#define SOFTROM_VECTOR_EXTENSION 1
typedef double Packet4 __attribute__((vector_size(32)));
typedef long long Mask4 __attribute__((vector_size(32)));
SOFTROM_INLINE Packet4 load_packet(const double* p) {
  Packet4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
#else
#define SOFTROM_VECTOR_EXTENSION 0
#endif

template <int T>
SOFTROM_INLINE void cols_dot_group(const double* __restrict a, Index rows,
                                   const double* __restrict x, double* __restrict out) {
  const Index whole = rows - rows % 4;
  double acc[T][4];
#if SOFTROM_VECTOR_EXTENSION
  Packet4 lanes[T];
  for (int t = 0; t < T; ++t) lanes[t] = Packet4{0.0, 0.0, 0.0, 0.0};
  for (Index r = 0; r < whole; r += 4) {
    const Packet4 xr = load_packet(x + r);
    for (int t = 0; t < T; ++t) lanes[t] += load_packet(a + t * rows + r) * xr;
  }
  if constexpr (T == 4) {
    if (whole == rows) {
      // The four columns' (s0 + s1) + (s2 + s3) as two rounds of pairwise sums across packets.
      const Packet4 h0 = __builtin_shuffle(lanes[0], lanes[1], Mask4{0, 4, 2, 6}) +
                         __builtin_shuffle(lanes[0], lanes[1], Mask4{1, 5, 3, 7});
      const Packet4 h1 = __builtin_shuffle(lanes[2], lanes[3], Mask4{0, 4, 2, 6}) +
                         __builtin_shuffle(lanes[2], lanes[3], Mask4{1, 5, 3, 7});
      const Packet4 sums = __builtin_shuffle(h0, h1, Mask4{0, 1, 4, 5}) +
                           __builtin_shuffle(h0, h1, Mask4{2, 3, 6, 7});
      std::memcpy(out, &sums, sizeof sums);
      return;
    }
  }
  for (int t = 0; t < T; ++t) std::memcpy(acc[t], &lanes[t], sizeof lanes[t]);
#else
  for (int t = 0; t < T; ++t)
    for (int l = 0; l < 4; ++l) acc[t][l] = 0.0;
  for (Index r = 0; r < whole; r += 4)
    for (int t = 0; t < T; ++t)
      for (int l = 0; l < 4; ++l) acc[t][l] += a[t * rows + r + l] * x[r + l];
#endif
  for (int t = 0; t < T; ++t) {
    for (Index r = whole; r < rows; ++r) acc[t][r - whole] += a[t * rows + r] * x[r];
    out[t] = (acc[t][0] + acc[t][1]) + (acc[t][2] + acc[t][3]);
  }
}

SOFTROM_INLINE void cols_dot_body(const double* __restrict a, Index rows, Index cols,
                                  const double* __restrict x, double* __restrict out) {
  Index c = 0;
  for (; c + 4 <= cols; c += 4) cols_dot_group<4>(a + c * rows, rows, x, out + c);
  for (; c < cols; ++c) cols_dot_group<1>(a + c * rows, rows, x, out + c);
}

// dots = A^T x, then out = A dots, in one sweep over A where its columns are whole packets in
// registers (rows a multiple of 4, at most 32): each group of columns' dot products, then their
// multiples added to out while the columns are in L1. The sums of cols_dot followed by
// cols_times (out's entries one multiply-add chain over the columns in order).
#if SOFTROM_VECTOR_EXTENSION
template <int P>
SOFTROM_INLINE void cols_dot_times_short(const double* __restrict a, Index cols,
                                         const double* __restrict x, double* __restrict dots,
                                         double* __restrict out) {
  constexpr Index rows = 4 * P;
  Packet4 acc[P];
  for (int p = 0; p < P; ++p) acc[p] = Packet4{0.0, 0.0, 0.0, 0.0};
  auto add_column = [&](Index c) {
    const double d = dots[c];
    const Packet4 dv{d, d, d, d};
    const double* __restrict ac = a + c * rows;
    for (int p = 0; p < P; ++p) acc[p] += dv * load_packet(ac + 4 * p);
  };
  Index c = 0;
  for (; c + 4 <= cols; c += 4) {
    cols_dot_group<4>(a + c * rows, rows, x, dots + c);
    for (int t = 0; t < 4; ++t) add_column(c + t);
  }
  for (; c < cols; ++c) {
    cols_dot_group<1>(a + c * rows, rows, x, dots + c);
    add_column(c);
  }
  for (int p = 0; p < P; ++p) std::memcpy(out + 4 * p, &acc[p], sizeof acc[p]);
}
#endif

SOFTROM_INLINE void cols_dot_times_body(const double* __restrict a, Index rows, Index cols,
                                        const double* __restrict x, double* __restrict dots,
                                        double* __restrict out) {
#if SOFTROM_VECTOR_EXTENSION
  if (rows % 4 == 0 && rows >= 4 && rows <= 32) {
    switch (rows / 4) {
      case 8: cols_dot_times_short<8>(a, cols, x, dots, out); return;
      case 7: cols_dot_times_short<7>(a, cols, x, dots, out); return;
      case 6: cols_dot_times_short<6>(a, cols, x, dots, out); return;
      case 5: cols_dot_times_short<5>(a, cols, x, dots, out); return;
      case 4: cols_dot_times_short<4>(a, cols, x, dots, out); return;
      case 3: cols_dot_times_short<3>(a, cols, x, dots, out); return;
      case 2: cols_dot_times_short<2>(a, cols, x, dots, out); return;
      default: cols_dot_times_short<1>(a, cols, x, dots, out); return;
    }
  }
#endif
  cols_dot_body(a, rows, cols, x, dots);
  cols_times_body(a, rows, cols, dots, out);
}

// Column i of out (leading dimension ld) = the combination of a's three rows 3 b_i .. 3 b_i + 2
// (row-major, `width` long) with weights w[3 i .. 3 i + 2], for i < count. N > 0 fixes the width
// at 4 N for the compiler: each column is then a few whole packets with no loop or remainder
// around them, a third of the instructions of the run-time width (N = 0) at the cross
// swimmer's 26 + 2 columns.
template <int N>
SOFTROM_INLINE void combine_row_triples_width(const double* __restrict a, Index run_width,
                                              const Index* __restrict blocks,
                                              const double* __restrict w, Index count,
                                              double* __restrict out, Index ld) {
  const Index width = N > 0 ? 4 * N : run_width;
  for (Index i = 0; i < count; ++i) {
    const double* __restrict r0 = a + 3 * blocks[i] * width;
    const double* __restrict r1 = r0 + width;
    const double* __restrict r2 = r1 + width;
    const double w0 = w[3 * i], w1 = w[3 * i + 1], w2 = w[3 * i + 2];
    double* __restrict o = out + i * ld;
    for (Index j = 0; j < width; ++j) o[j] = w0 * r0[j] + w1 * r1[j] + w2 * r2[j];
  }
}

SOFTROM_INLINE void combine_row_triples_body(const double* __restrict a, Index width,
                                             const Index* __restrict blocks,
                                             const double* __restrict w, Index count,
                                             double* __restrict out, Index ld) {
  if (width % 4 == 0 && width >= 4 && width <= 32) {
    switch (width / 4) {
      case 8: combine_row_triples_width<8>(a, width, blocks, w, count, out, ld); return;
      case 7: combine_row_triples_width<7>(a, width, blocks, w, count, out, ld); return;
      case 6: combine_row_triples_width<6>(a, width, blocks, w, count, out, ld); return;
      case 5: combine_row_triples_width<5>(a, width, blocks, w, count, out, ld); return;
      case 4: combine_row_triples_width<4>(a, width, blocks, w, count, out, ld); return;
      case 3: combine_row_triples_width<3>(a, width, blocks, w, count, out, ld); return;
      case 2: combine_row_triples_width<2>(a, width, blocks, w, count, out, ld); return;
      default: combine_row_triples_width<1>(a, width, blocks, w, count, out, ld); return;
    }
  }
  combine_row_triples_width<0>(a, width, blocks, w, count, out, ld);
}

// K columns [c, c + K) of a tall A added to two outputs in one pass over it, out_x += A x and
// out_y += A y: each entry the same multiply-add chain over the columns as cols_times_pass
// gives it, with A read once for both.
template <int K, bool First = false>
SOFTROM_INLINE void cols_times_pair_pass(const double* __restrict a, Index rows, Index c,
                                         const double* __restrict x, const double* __restrict y,
                                         double* __restrict out_x, double* __restrict out_y) {
  double xs[K], ys[K];
  for (int t = 0; t < K; ++t) {
    xs[t] = x[c + t];
    ys[t] = y[c + t];
  }
  const double* __restrict a0 = a + c * rows;
  for (Index r = 0; r < rows; ++r) {
    double o = First ? 0.0 : out_x[r];
    double p = First ? 0.0 : out_y[r];
    for (int t = 0; t < K; ++t) {
      const double v = a0[t * rows + r];
      o += xs[t] * v;
      p += ys[t] * v;
    }
    out_x[r] = o;
    out_y[r] = p;
  }
}

SOFTROM_INLINE void cols_times_pair_body(const double* __restrict a, Index rows, Index cols,
                                         const double* __restrict x, const double* __restrict y,
                                         double* __restrict out_x, double* __restrict out_y) {
  if (rows <= 32 || cols < 4) {  // short outputs: in registers, one product at a time
    cols_times_body(a, rows, cols, x, out_x);
    cols_times_body(a, rows, cols, y, out_y);
    return;
  }
  cols_times_pair_pass<4, true>(a, rows, 0, x, y, out_x, out_y);
  Index c = 4;
  for (; c + 4 <= cols; c += 4) cols_times_pair_pass<4>(a, rows, c, x, y, out_x, out_y);
  switch (cols - c) {
    case 3: cols_times_pair_pass<3>(a, rows, c, x, y, out_x, out_y); break;
    case 2: cols_times_pair_pass<2>(a, rows, c, x, y, out_x, out_y); break;
    case 1: cols_times_pair_pass<1>(a, rows, c, x, y, out_x, out_y); break;
    default: break;
  }
}

SOFTROM_INLINE void lower_solve_rows_body(const double* __restrict l, Index n,
                                          double* __restrict b, Index nrhs) {
  for (Index i = 0; i < n; ++i) {
    double* __restrict bi = b + i * nrhs;
    for (Index j = 0; j < i; ++j) {
      const double lij = l[i + j * n];
      if (lij == 0.0) continue;
      const double* __restrict bj = b + j * nrhs;
      for (Index c = 0; c < nrhs; ++c) bi[c] -= lij * bj[c];
    }
    const double inv = 1.0 / l[i + i * n];
    for (Index c = 0; c < nrhs; ++c) bi[c] *= inv;
  }
}

// Column i of the lower Cholesky factor, rows [i, i + 4 N) (N = ceil((n - i) / 4); the rows past
// n are the caller's zero padding): the 4 N entries stay in registers while the earlier
// columns stream past, each subtracting L(i, k) times its rows, in k's order: entry (j, i) is
// a_ji - L(i,0) L(j,0) - L(i,1) L(j,1) - ..., Cholesky-Crout's sum in its order.
template <int N, bool kLanes>
SOFTROM_INLINE void cholesky_lower_column(double* __restrict a, Index lda, Index i) {
  double* __restrict ci = a + i * lda + i;
  if constexpr (kLanes) {
    Lanes4 acc[N];
    for (int v = 0; v < N; ++v) acc[v] = *reinterpret_cast<const Lanes4*>(ci + 4 * v);
    for (Index k = 0; k < i; ++k) {
      const double* __restrict ck = a + k * lda + i;
      const double lik = ck[0];
      for (int v = 0; v < N; ++v)
        acc[v] = acc[v] - *reinterpret_cast<const Lanes4*>(ck + 4 * v) * lik;
    }
    for (int v = 0; v < N; ++v) *reinterpret_cast<Lanes4*>(ci + 4 * v) = acc[v];
  } else {
    double acc[4 * N];
    for (int r = 0; r < 4 * N; ++r) acc[r] = ci[r];
    for (Index k = 0; k < i; ++k) {
      const double* __restrict ck = a + k * lda + i;
      const double lik = ck[0];
      for (int r = 0; r < 4 * N; ++r) acc[r] = acc[r] - ck[r] * lik;
    }
    for (int r = 0; r < 4 * N; ++r) ci[r] = acc[r];
  }
}

template <bool kLanes>
SOFTROM_INLINE bool cholesky_lower_body(double* __restrict a, Index n, Index lda) {
  for (Index i = 0; i < n; ++i) {
    switch ((n - i + 3) / 4) {
      case 1: cholesky_lower_column<1, kLanes>(a, lda, i); break;
      case 2: cholesky_lower_column<2, kLanes>(a, lda, i); break;
      case 3: cholesky_lower_column<3, kLanes>(a, lda, i); break;
      case 4: cholesky_lower_column<4, kLanes>(a, lda, i); break;
      case 5: cholesky_lower_column<5, kLanes>(a, lda, i); break;
      case 6: cholesky_lower_column<6, kLanes>(a, lda, i); break;
      case 7: cholesky_lower_column<7, kLanes>(a, lda, i); break;
      case 8: cholesky_lower_column<8, kLanes>(a, lda, i); break;
      default:  // wider than 32 rows: the same sums, 32 rows at a time
        for (Index r0 = i; r0 < n; r0 += 32) {
          double* __restrict ci = a + i * lda;
          double acc[32];
          const Index len = n - r0 < 32 ? n - r0 : 32;
          for (Index r = 0; r < len; ++r) acc[r] = ci[r0 + r];
          for (Index k = 0; k < i; ++k) {
            const double lik = a[i + k * lda];
            const double* __restrict ck = a + k * lda + r0;
            for (Index r = 0; r < len; ++r) acc[r] = acc[r] - ck[r] * lik;
          }
          for (Index r = 0; r < len; ++r) ci[r0 + r] = acc[r];
        }
    }
    double* __restrict ci = a + i * lda;
    const double d = ci[i];
    if (!(d > 0.0) || !std::isfinite(d)) return false;
    const double lii = std::sqrt(d);
    ci[i] = lii;
    for (Index j = i + 1; j < n; ++j) ci[j] = ci[j] / lii;
  }
  return true;
}

// H G for the stable Neo-Hookean H = w (mu I + lambda g g^T + s d(cof F)/dF) without forming
// H: per column of G (one lane), with X_c = the lane's three rows of column c of dF,
//   (H G)_c = w mu X_c + (w lambda g_c) (g . X) + (ws f_a x X_b - ws f_b x X_a),
// (a, b) = (1, 2), (2, 0), (0, 1), the cofactor's derivative d(f_a x f_b) with ws f = w s F.
// 63 multiply-adds per lane against the dense 9 x 9 product's 81, and no 9 x 9 matrix.
SOFTROM_INLINE void snh_element_hg_body(const double* __restrict coef, const double* __restrict g,
                                        Index width, double* __restrict out) {
  const double g0 = coef[0], g1 = coef[1], g2 = coef[2], g3 = coef[3], g4 = coef[4];
  const double g5 = coef[5], g6 = coef[6], g7 = coef[7], g8 = coef[8];
  const double c0 = coef[9], c1 = coef[10], c2 = coef[11], c3 = coef[12], c4 = coef[13];
  const double c5 = coef[14], c6 = coef[15], c7 = coef[16], c8 = coef[17];
  const double p0 = coef[18], p1 = coef[19], p2 = coef[20];  // ws f_0
  const double q0 = coef[21], q1 = coef[22], q2 = coef[23];  // ws f_1
  const double r0 = coef[24], r1 = coef[25], r2 = coef[26];  // ws f_2
  const double wmu = coef[27];
  SOFTROM_IVDEP
  for (Index l = 0; l < width; ++l) {
    const double x0 = g[l], x1 = g[width + l], x2 = g[2 * width + l];
    const double y0 = g[3 * width + l], y1 = g[4 * width + l], y2 = g[5 * width + l];
    const double z0 = g[6 * width + l], z1 = g[7 * width + l], z2 = g[8 * width + l];
    const double t = g0 * x0 + g1 * x1 + g2 * x2 + g3 * y0 + g4 * y1 + g5 * y2 + g6 * z0 +
                     g7 * z1 + g8 * z2;
    // column 0 of cof: f_1 x f_2, derivative q x Z - r x Y
    out[l] = wmu * x0 + c0 * t + ((q1 * z2 - q2 * z1) - (r1 * y2 - r2 * y1));
    out[width + l] = wmu * x1 + c1 * t + ((q2 * z0 - q0 * z2) - (r2 * y0 - r0 * y2));
    out[2 * width + l] = wmu * x2 + c2 * t + ((q0 * z1 - q1 * z0) - (r0 * y1 - r1 * y0));
    // column 1: f_2 x f_0, derivative r x X - p x Z
    out[3 * width + l] = wmu * y0 + c3 * t + ((r1 * x2 - r2 * x1) - (p1 * z2 - p2 * z1));
    out[4 * width + l] = wmu * y1 + c4 * t + ((r2 * x0 - r0 * x2) - (p2 * z0 - p0 * z2));
    out[5 * width + l] = wmu * y2 + c5 * t + ((r0 * x1 - r1 * x0) - (p0 * z1 - p1 * z0));
    // column 2: f_0 x f_1, derivative p x Y - q x X
    out[6 * width + l] = wmu * z0 + c6 * t + ((p1 * y2 - p2 * y1) - (q1 * x2 - q2 * x1));
    out[7 * width + l] = wmu * z1 + c7 * t + ((p2 * y0 - p0 * y2) - (q2 * x0 - q0 * x2));
    out[8 * width + l] = wmu * z2 + c8 * t + ((p0 * y1 - p1 * y0) - (q0 * x1 - q1 * x0));
  }
}

// The stable Neo-Hookean arithmetic on four lanes, one element per lane: from the nine entries
// of F - I (column-major vec), the weighted stress w P(F) into out and the weighted energy
// density w psi(F) into e. A lane with F = I and w = 0 (padding) gets zeros.
SOFTROM_INLINE void snh_lanes(const double (&f)[9][4], const double* __restrict wl, double mu,
                              double lambda, double (&out)[9][4], double (&e)[4]) {
  for (int l = 0; l < 4; ++l) {
    const double x0 = f[0][l] + 1.0, x1 = f[1][l], x2 = f[2][l];  // column f_0 of F
    const double y0 = f[3][l], y1 = f[4][l] + 1.0, y2 = f[5][l];  // f_1
    const double z0 = f[6][l], z1 = f[7][l], z2 = f[8][l] + 1.0;  // f_2
    // cof F = [f_1 x f_2, f_2 x f_0, f_0 x f_1], det F = f_0 . (f_1 x f_2)
    const double c0 = y1 * z2 - y2 * z1, c1 = y2 * z0 - y0 * z2, c2 = y0 * z1 - y1 * z0;
    const double c3 = z1 * x2 - z2 * x1, c4 = z2 * x0 - z0 * x2, c5 = z0 * x1 - z1 * x0;
    const double c6 = x1 * y2 - x2 * y1, c7 = x2 * y0 - x0 * y2, c8 = x0 * y1 - x1 * y0;
    const double jm1 = (x0 * c0 + x1 * c1 + x2 * c2) - 1.0;
    const double sq = (x0 * x0 + x1 * x1 + x2 * x2) + (y0 * y0 + y1 * y1 + y2 * y2) +
                      (z0 * z0 + z1 * z1 + z2 * z2);
    e[l] = wl[l] * (0.5 * mu * (sq - 3.0) - mu * jm1 + 0.5 * lambda * jm1 * jm1);
    const double a = wl[l] * mu, b = wl[l] * (lambda * jm1 - mu);
    out[0][l] = a * x0 + b * c0;
    out[1][l] = a * x1 + b * c1;
    out[2][l] = a * x2 + b * c2;
    out[3][l] = a * y0 + b * c3;
    out[4][l] = a * y1 + b * c4;
    out[5][l] = a * y2 + b * c5;
    out[6][l] = a * z0 + b * c6;
    out[7][l] = a * z1 + b * c7;
    out[8][l] = a * z2 + b * c8;
  }
}

// F - I = G_g q for one group of four elements of the interleaved G (dense_kernels.h): nine
// 4-lane sums, each one multiply-add chain over q's entries in order (the chains cols_times
// made on a column-major copy of G, which this layout replaced: F is the same to the bit).
SOFTROM_INLINE void group_deformation(const double* __restrict blk, Index width,
                                      const double* __restrict q, double (&f)[9][4]) {
#if SOFTROM_VECTOR_EXTENSION
  Packet4 acc[9];
  for (int i = 0; i < 9; ++i) acc[i] = Packet4{0.0, 0.0, 0.0, 0.0};
  for (Index j = 0; j < width; ++j) {
    const double qj = q[j];
    const Packet4 qv = {qj, qj, qj, qj};
    for (int i = 0; i < 9; ++i) acc[i] += qv * load_packet(blk + 36 * j + 4 * i);
  }
  for (int i = 0; i < 9; ++i) std::memcpy(f[i], &acc[i], sizeof acc[i]);
#else
  for (int i = 0; i < 9; ++i)
    for (int l = 0; l < 4; ++l) f[i][l] = 0.0;
  for (Index j = 0; j < width; ++j)
    for (int i = 0; i < 9; ++i)
      for (int l = 0; l < 4; ++l) f[i][l] += q[j] * blk[36 * j + 4 * i + l];
#endif
}

// The cubature energy and G^T P in one pass over the interleaved G: per group of four
// elements, F - I = G_g q, the stresses on the lanes, then G_g^T P into per-lane partial sums
// of each of G's columns, while the group's 36 x width block is still in L1. Reading G once
// per evaluation, not twice (G q and G^T P each streamed a copy of G from L2, the force's
// bound: benchmarks/PROFILE.md, session 22). The partial sums are combined as
// (s0 + s1) + (s2 + s3) at the end; the energy is summed over the elements in order.
SOFTROM_INLINE double snh_force_body(const double* __restrict gi, Index groups, Index width,
                                     const double* __restrict q, const double* __restrict w,
                                     double mu, double lambda, double* __restrict lanes,
                                     double* __restrict gtp) {
  for (Index j = 0; j < 4 * width; ++j) lanes[j] = 0.0;
  double energy = 0.0;
  for (Index g = 0; g < groups; ++g) {
    const double* blk = gi + 36 * width * g;
    double f[9][4], p[9][4], e[4];
    group_deformation(blk, width, q, f);
    snh_lanes(f, w + 4 * g, mu, lambda, p, e);
#if SOFTROM_VECTOR_EXTENSION
    Packet4 pv[9];
    for (int i = 0; i < 9; ++i) std::memcpy(&pv[i], p[i], sizeof pv[i]);
    for (Index j = 0; j < width; ++j) {
      Packet4 s = load_packet(lanes + 4 * j);
      for (int i = 0; i < 9; ++i) s += load_packet(blk + 36 * j + 4 * i) * pv[i];
      std::memcpy(lanes + 4 * j, &s, sizeof s);
    }
#else
    for (Index j = 0; j < width; ++j)
      for (int i = 0; i < 9; ++i)
        for (int l = 0; l < 4; ++l) lanes[4 * j + l] += blk[36 * j + 4 * i + l] * p[i][l];
#endif
    for (int l = 0; l < 4; ++l) energy += e[l];
  }
  for (Index j = 0; j < width; ++j)
    gtp[j] = (lanes[4 * j] + lanes[4 * j + 1]) + (lanes[4 * j + 2] + lanes[4 * j + 3]);
  return energy;
}

// F - I for the first `count` elements of the interleaved G, element-major (9 entries each).
SOFTROM_INLINE void interleaved_deformation_body(const double* __restrict gi, Index count,
                                                 Index width, const double* __restrict q,
                                                 double* __restrict f_minus_i) {
  for (Index k0 = 0; k0 < count; k0 += 4) {
    double f[9][4];
    group_deformation(gi + 9 * width * k0, width, q, f);
    const int lanes = count - k0 < 4 ? static_cast<int>(count - k0) : 4;
    for (int l = 0; l < lanes; ++l)
      for (int i = 0; i < 9; ++i) f_minus_i[9 * (k0 + l) + i] = f[i][l];
  }
}

// Each kernel twice: the same body compiled for the baseline and for x86-64-v3.
struct Table {
  const char* name;
  void (*gram_lower)(const double*, const double*, Index, Index, double*);
  void (*gram_lower_add)(const double*, const double*, Index, Index, double*);
  void (*cols_times)(const double*, Index, Index, const double*, double*);
  void (*cols_dot)(const double*, Index, Index, const double*, double*);
  void (*cols_times_pair)(const double*, Index, Index, const double*, const double*, double*,
                          double*);
  void (*cols_dot_times)(const double*, Index, Index, const double*, double*, double*);
  void (*combine_row_triples)(const double*, Index, const Index*, const double*, Index, double*,
                              Index);
  void (*snh_element_hg)(const double*, const double*, Index, double*);
  double (*snh_force)(const double*, Index, Index, const double*, const double*, double, double,
                      double*, double*);
  void (*interleaved_deformation)(const double*, Index, Index, const double*, double*);
  void (*lower_solve_rows)(const double*, Index, double*, Index);
  bool (*cholesky_lower)(double*, Index, Index);
};

#define SOFTROM_KERNEL_SET(attr, contract_off, suffix, wide)                                   \
  attr void gram_lower_##suffix(const double* g, const double* x, Index rows, Index width,     \
                                double* out) {                                                 \
    gram_lower_body<wide>(g, x, rows, width, out);                                             \
  }                                                                                            \
  attr void gram_lower_add_##suffix(const double* g, const double* x, Index rows, Index width, \
                                    double* out) {                                             \
    gram_lower_add_body<wide>(g, x, rows, width, out);                                         \
  }                                                                                            \
  attr void cols_times_##suffix(const double* a, Index rows, Index cols, const double* x,      \
                                double* out) {                                                 \
    cols_times_body(a, rows, cols, x, out);                                                    \
  }                                                                                            \
  attr void cols_dot_##suffix(const double* a, Index rows, Index cols, const double* x,        \
                              double* out) {                                                   \
    cols_dot_body(a, rows, cols, x, out);                                                      \
  }                                                                                            \
  attr void cols_times_pair_##suffix(const double* a, Index rows, Index cols, const double* x, \
                                     const double* y, double* out_x, double* out_y) {          \
    cols_times_pair_body(a, rows, cols, x, y, out_x, out_y);                                   \
  }                                                                                            \
  attr void cols_dot_times_##suffix(const double* a, Index rows, Index cols, const double* x,  \
                                    double* dots, double* out) {                               \
    cols_dot_times_body(a, rows, cols, x, dots, out);                                          \
  }                                                                                            \
  attr void combine_row_triples_##suffix(const double* a, Index width, const Index* blocks,    \
                                         const double* w, Index count, double* out, Index ld) { \
    combine_row_triples_body(a, width, blocks, w, count, out, ld);                             \
  }                                                                                            \
  attr void snh_element_hg_##suffix(const double* coef, const double* g, Index width,          \
                                    double* out) {                                             \
    snh_element_hg_body(coef, g, width, out);                                                  \
  }                                                                                            \
  attr double snh_force_##suffix(const double* gi, Index groups, Index width, const double* q, \
                                 const double* w, double mu, double lambda, double* lanes,     \
                                 double* gtp) {                                                \
    return snh_force_body(gi, groups, width, q, w, mu, lambda, lanes, gtp);                    \
  }                                                                                            \
  attr void interleaved_deformation_##suffix(const double* gi, Index count, Index width,       \
                                             const double* q, double* f_minus_i) {             \
    interleaved_deformation_body(gi, count, width, q, f_minus_i);                              \
  }                                                                                            \
  attr void lower_solve_rows_##suffix(const double* l, Index n, double* b, Index nrhs) {       \
    lower_solve_rows_body(l, n, b, nrhs);                                                      \
  }                                                                                            \
  attr contract_off bool cholesky_lower_##suffix(double* a, Index n, Index lda) {              \
    return cholesky_lower_body<wide>(a, n, lda);                                               \
  }

SOFTROM_KERNEL_SET(, , baseline, false)
#if SOFTROM_KERNEL_DISPATCH
// (cholesky_lower's v3 build does not fuse its products and differences: multiply-adds there
// bought ~5 % in a harness, and unfused it gives the factor of small::cholesky_upper, the
// baseline's loops, to the bit.)
SOFTROM_KERNEL_SET(__attribute__((target("arch=x86-64-v3"))),
                   __attribute__((optimize("fp-contract=off"))), v3, true)
#endif

const Table& table() {
  // Chosen once, on first use: x86-64-v3 where the CPU has it, unless SOFTROM_KERNELS=baseline
  // asks for the baseline (the same round-off as a machine without AVX2).
  static const Table chosen = [] {
    const Table baseline{"baseline", gram_lower_baseline, gram_lower_add_baseline,
                         cols_times_baseline, cols_dot_baseline, cols_times_pair_baseline,
                         cols_dot_times_baseline, combine_row_triples_baseline,
                         snh_element_hg_baseline, snh_force_baseline,
                         interleaved_deformation_baseline, lower_solve_rows_baseline,
                         cholesky_lower_baseline};
#if SOFTROM_KERNEL_DISPATCH
    const char* want = std::getenv("SOFTROM_KERNELS");
    const bool forced = want != nullptr && std::strcmp(want, "baseline") == 0;
    __builtin_cpu_init();
    if (!forced && __builtin_cpu_supports("x86-64-v3"))
      return Table{"x86-64-v3",        gram_lower_v3,     gram_lower_add_v3,
                   cols_times_v3,      cols_dot_v3,       cols_times_pair_v3,
                   cols_dot_times_v3,  combine_row_triples_v3,
                   snh_element_hg_v3,  snh_force_v3,
                   interleaved_deformation_v3,         lower_solve_rows_v3,
                   cholesky_lower_v3};
#endif
    return baseline;
  }();
  return chosen;
}

}  // namespace

const char* instruction_set() { return table().name; }

void gram_lower(const double* g, const double* x, Index rows, Index width, double* out) {
  table().gram_lower(g, x, rows, width, out);
}
void gram_lower_add(const double* g, const double* x, Index rows, Index width, double* out) {
  table().gram_lower_add(g, x, rows, width, out);
}
void cols_times(const double* a, Index rows, Index cols, const double* x, double* out) {
  table().cols_times(a, rows, cols, x, out);
}
void cols_dot(const double* a, Index rows, Index cols, const double* x, double* out) {
  table().cols_dot(a, rows, cols, x, out);
}
void cols_times_pair(const double* a, Index rows, Index cols, const double* x, const double* y,
                     double* out_x, double* out_y) {
  table().cols_times_pair(a, rows, cols, x, y, out_x, out_y);
}
void cols_dot_times(const double* a, Index rows, Index cols, const double* x, double* dots,
                    double* out) {
  table().cols_dot_times(a, rows, cols, x, dots, out);
}
void combine_row_triples(const double* a, Index width, const Index* blocks, const double* w,
                         Index count, double* out, Index ld) {
  table().combine_row_triples(a, width, blocks, w, count, out, ld);
}
void snh_element_hg(const double* coef, const double* g, Index width, double* out) {
  table().snh_element_hg(coef, g, width, out);
}
double snh_force(const double* gi, Index groups, Index width, const double* q, const double* w,
                 double mu, double lambda, double* lanes, double* gtp) {
  return table().snh_force(gi, groups, width, q, w, mu, lambda, lanes, gtp);
}
void interleaved_deformation(const double* gi, Index count, Index width, const double* q,
                             double* f_minus_i) {
  table().interleaved_deformation(gi, count, width, q, f_minus_i);
}
void lower_solve_rows(const double* l, Index n, double* b, Index nrhs) {
  table().lower_solve_rows(l, n, b, nrhs);
}

bool cholesky_lower(double* a, Index n, Index lda) { return table().cholesky_lower(a, n, lda); }

}  // namespace softrom::kernels
