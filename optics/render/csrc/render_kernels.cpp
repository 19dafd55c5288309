// Gaussian scatter filter on CPU (see optics/_render_ops.py for the maths and the PyTorch twin).
//
//   y_c(p) = sum_q norm_q * t_q(py - qy) * t_q(px - qx) * x_c(q),  t_q(d) = exp(-d^2 / (2 s_q^2))
//
// over |p - q|_inf <= half, q and p inside the image. Arrays are contiguous (B, C, H, W), sigma and
// norm (B, 1, H, W). The per-source table t_q(0..half) is built by the recurrence
// t(d+1) = t(d) * e^(2d+1), e = exp(-1 / (2 s^2)): one exp per source pixel.
// Also the clamped-distance profiles of the disk and the polygons (below).
// Plain C ABI (loaded with ctypes, wrapped as torch.library custom ops by optics/_render_ops.py):
// no PyTorch headers, so it compiles in a few seconds.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>
#ifdef __linux__
#include <sys/mman.h>
#endif

namespace {

template <typename T>
void fill_table(const T* sigma_row, int64_t width, int64_t half, T* table, int64_t stride) {
  // table[d * stride + s] = exp(-d^2 / (2 sigma_s^2)), d = 0..half
  for (int64_t s = 0; s < width; ++s) table[s] = T(1);
  if (half == 0) return;
  for (int64_t s = 0; s < width; ++s) {
    const T sg = sigma_row[s];
    const T e = std::exp(T(-0.5) / (sg * sg));
    const T e2 = e * e;
    T t = T(1), q = e;
    for (int64_t d = 1; d <= half; ++d) {
      t *= q;
      q *= e2;
      table[d * stride + s] = t;
    }
  }
}

// Register blocks of two 32-byte vectors (GCC/Clang vector extensions; without AVX the compiler
// splits them into SSE halves): 16 float or 8 double output pixels per block.
template <typename T>
struct Vec {
  typedef T type __attribute__((vector_size(32), aligned(sizeof(T))));
  static constexpr int64_t lanes = 32 / sizeof(T);
};
template <typename T>
using V = typename Vec<T>::type;
template <typename T>
inline V<T> load(const T* p) {
  return *reinterpret_cast<const V<T>*>(p);
}
constexpr int64_t kVectors = 2;
template <typename T>
constexpr int64_t block_lanes() {
  return kVectors * Vec<T>::lanes;
}
constexpr int64_t kRowVectors = 1;     // vectors per row in the two-row register blocks
constexpr int64_t kPadRight = 16;      // >= block_lanes<T>() for float and double
// Rows per task: the ring of source rows is reused along a task, so longer tasks refill fewer
// rows (a task of R rows reads R + K - 1), while enough tasks must remain for the threads.
inline int64_t rows_per_block(int64_t B, int64_t H, int nthreads) {
  const int64_t rows = (B * H) / (4 * std::max(nthreads, 1));
  return std::max<int64_t>(16, std::min<int64_t>(64, rows & ~int64_t(1)));
}

// Ring of per-row buffers, padded by `half` on the left and half + kPadRight on the right with
// zeros, so that the register blocks need no bounds checks (zero weight, finite values).
template <typename T>
struct RowRing {
  int64_t half, width, padded, rows_per_slot;
  std::vector<T> data;
  std::vector<int64_t> row_of_slot;
  RowRing(int64_t K, int64_t half_, int64_t width_, int64_t rows)
      : half(half_), width(width_), padded(width_ + 2 * half_ + kPadRight), rows_per_slot(rows),
        data(K * rows * padded, T(0)), row_of_slot(K, -1) {}
  void reset() { std::fill(row_of_slot.begin(), row_of_slot.end(), int64_t(-1)); }
  // Buffer of the slot holding image row y; index half + s of each of its rows is pixel s.
  T* slot(int64_t y, bool* fresh) {
    const int64_t k = y % static_cast<int64_t>(row_of_slot.size());
    *fresh = row_of_slot[k] != y;
    row_of_slot[k] = y;
    return data.data() + k * rows_per_slot * padded;
  }
};

// ---------------------------------------------------------------------------------------------
// Clamped-distance profiles (the disk and the polygons, optics.Disk and its subclasses):
//
//   w_q(u) = clamp(rho_q - D(u), 0, 1),   rho_q = edge_radius(c_q) + 1/2,  D(u) >= 0, D(0) = 0
//
// D is the aperture's distance function tabulated on the K x K window (row-major, u = (dy, dx) =
// output - source), independent of the CoC. Forward: y_c(p) = sum_q norm_q w_q(p - q) x_c(q).
template <typename T>
inline V<T> clamp01(V<T> t) {
  const V<T> zero = V<T>{} , one = zero + T(1);
  t = t < zero ? zero : t;
  return t > one ? one : t;
}

// ---------------------------------------------------------------------------------------------
// Weight policies: the per-source parameter a_q (sigma for the Gaussian, rho for the clamped
// distance) gives the weights w_q(u), their derivative dw_q/da and the window's total Z_q. A
// policy's weight rows live in each ring slot, ahead of the channels; the kernels below are
// written once over the policy.

// Gaussian: weight rows t(d), d = 0..half; w = t(|dy|) t(|dx|); dw/dsigma = w |u|^2 / sigma^3.
template <typename T>
struct GaussPolicy {
  int64_t half;
  int64_t rows() const { return half + 1; }
  // The weight rows alone: rows[d * padded + s] = t_s(d).
  void fill_rows(const T* sigma, int64_t W, T* rows, int64_t padded) const {
    fill_table(sigma, W, half, rows, padded);
  }
  // line = sum_{d=-half..half} t(d), moment = sum_d d^2 t(d) (see window_sums).
  void sums(T sg, T* line, T* moment) const {
    const T e = std::exp(T(-0.5) / (sg * sg));
    const T e2 = e * e;
    T t = T(1), q = e, l = T(1), m = T(0);
    for (int64_t d = 1; d <= half; ++d) {
      t *= q;
      q *= e2;
      l += T(2) * t;
      m += T(2 * d * d) * t;
    }
    *line = l;
    *moment = m;
  }
  // rows[d * padded + s] = t_s(d); norm[s] = 1 / line_s^2; dnorm[s] = d norm / d sigma.
  void fill(const T* sigma, int64_t W, T* rows, int64_t padded, T* norm, T* dnorm, T* scratch) const {
    T* q = scratch;
    T* e2 = scratch + W;
    T* line = scratch + 2 * W;
    T* moment = scratch + 3 * W;
    for (int64_t s = 0; s < W; ++s) {
      const T e = std::exp(T(-0.5) / (sigma[s] * sigma[s]));
      q[s] = e;
      e2[s] = e * e;
      rows[s] = T(1);
      line[s] = T(1);
      moment[s] = T(0);
    }
    for (int64_t d = 1; d <= half; ++d) {
      const T* prev = rows + (d - 1) * padded;
      T* cur = rows + d * padded;
      const T dd = T(2 * d * d);
      for (int64_t s = 0; s < W; ++s) {
        const T t = prev[s] * q[s];
        q[s] *= e2[s];
        cur[s] = t;
        line[s] += T(2) * t;
        moment[s] += dd * t;
      }
    }
    for (int64_t s = 0; s < W; ++s) {
      const T inv = T(1) / line[s];
      norm[s] = inv * inv;
      if (dnorm != nullptr) {
        const T sg = sigma[s];
        dnorm[s] = T(-2) * moment[s] * inv * inv * inv / (sg * sg * sg);
      }
    }
  }
  V<T> weight(const T* rows, int64_t padded, int64_t dy, int64_t dx, int64_t idx) const {
    return load(rows + std::abs(dy) * padded + idx) * load(rows + std::abs(dx) * padded + idx);
  }
  // Weights at (dy, dx) and (dy + 1, dx), sharing the load of t(|dx|).
  void weight2(const T* rows, int64_t padded, int64_t dy, int64_t dx, int64_t idx, V<T>* w0,
               V<T>* w1) const {
    const V<T> tx = load(rows + std::abs(dx) * padded + idx);
    *w0 = load(rows + std::abs(dy) * padded + idx) * tx;
    *w1 = load(rows + std::abs(dy + 1) * padded + idx) * tx;
  }
  // w and dw/da without the per-source factor (1 / sigma^3, applied by scale()).
  void weights(const T* rows, int64_t padded, int64_t dy, int64_t dx, int64_t idx, V<T>* w,
               V<T>* dw) const {
    *w = weight(rows, padded, dy, dx, idx);
    *dw = *w * T(dy * dy + dx * dx);
  }
  T scale(T sigma) const { return T(1) / (sigma * sigma * sigma); }
};

// Clamped distance: one weight row, rho; w = clamp(rho - D(u), 0, 1), dw/drho = [0 <= . <= 1].
template <typename T>
struct ClampPolicy {
  int64_t half;
  const T* dist;    // K x K, row-major, u = (dy, dx)
  const T* dists;   // the window's distinct distances
  const T* counts;  // and their multiplicities
  int64_t n_dists;
  int64_t rows() const { return 1; }
  void fill_rows(const T* rho, int64_t W, T* rows, int64_t) const { std::copy(rho, rho + W, rows); }
  // Z = sum_j count_j clamp(r - d_j, 0, 1), dZ/dr = sum_j count_j [0 <= r - d_j <= 1] over the
  // window's distinct distances d_j (with multiplicities count_j).
  void sums(T r, T* total, T* slope) const {
    T z = T(0), sl = T(0);
    for (int64_t j = 0; j < n_dists; ++j) {
      const T t = r - dists[j];
      z += counts[j] * std::min(std::max(t, T(0)), T(1));
      sl += (t >= T(0) && t <= T(1)) ? counts[j] : T(0);
    }
    *total = z;
    *slope = sl;
  }
  void fill(const T* rho, int64_t W, T* rows, int64_t, T* norm, T* dnorm, T*) const {
    for (int64_t s = 0; s < W; ++s) {
      const T r = rho[s];
      T z, sl;
      sums(r, &z, &sl);
      rows[s] = r;
      norm[s] = T(1) / z;
      if (dnorm != nullptr) dnorm[s] = -sl / (z * z);
    }
  }
  V<T> weight(const T* rows, int64_t, int64_t dy, int64_t dx, int64_t idx) const {
    const int64_t K = 2 * half + 1;
    return clamp01<T>(load(rows + idx) - dist[(dy + half) * K + dx + half]);
  }
  void weight2(const T* rows, int64_t, int64_t dy, int64_t dx, int64_t idx, V<T>* w0,
               V<T>* w1) const {
    const int64_t K = 2 * half + 1;
    const V<T> r = load(rows + idx);
    *w0 = clamp01<T>(r - dist[(dy + half) * K + dx + half]);
    *w1 = clamp01<T>(r - dist[(dy + 1 + half) * K + dx + half]);
  }
  void weights(const T* rows, int64_t, int64_t dy, int64_t dx, int64_t idx, V<T>* w,
               V<T>* dw) const {
    const int64_t K = 2 * half + 1;
    const V<T> zero = V<T>{}, one = zero + T(1);
    const V<T> t = load(rows + idx) - dist[(dy + half) * K + dx + half];
    *w = clamp01<T>(t);
    *dw = (t >= zero) & (t <= one) ? one : zero;
  }
  T scale(T) const { return T(1); }
};

// ---------------------------------------------------------------------------------------------
// Unnormalised scatter with a per-source factor norm (optics/_render_ops.py: gaussian_scatter,
// clamp_scatter and their gathers):
//
//   y_c(p) = sum_q norm_q w_q(p - q) x_c(q)                                       (forward)
//   dx_raw_c(q) = sum_u w_q(u) g_c(q+u),  m(q) = sum_c x_c(q) sum_u dw_q(u) g_c(q+u)  (backward)
//
// dw without the policy's scale() (the Gaussian's m1 = sum_c x_c sum_u t_q(u) |u|^2 g_c(q+u)).

// Forward for G channels of one output row, one register block starting at output pixel x0.
template <typename T, int G, class P>
void scatter_forward_group(const P& pol, const T* const* xn_rows, const T* const* w_rows,
                           int64_t padded, int64_t x0, T* out, int64_t out_stride, int64_t n_out,
                           int64_t n_groups) {
  constexpr int64_t L = Vec<T>::lanes;
  const int64_t half = pol.half;
  V<T> acc[G][kVectors];
  for (int g = 0; g < G; ++g)
    for (int j = 0; j < kVectors; ++j) acc[g][j] = V<T>{};
  const int64_t K = 2 * half + 1;
  for (int64_t k = 0; k < K; ++k) {  // source row oy - dy, dy = k - half
    const T* wr = w_rows[k];
    if (wr == nullptr) continue;
    const int64_t dy = k - half;
    const T* const* xr = xn_rows + k * G;
    for (int64_t dx = -half; dx <= half; ++dx) {
      const int64_t base = x0 - dx + half;
      for (int j = 0; j < kVectors; ++j) {
        const V<T> w = pol.weight(wr, padded, dy, dx, base + j * L);
        for (int g = 0; g < G; ++g) acc[g][j] += w * load(xr[g] + base + j * L);
      }
    }
  }
  for (int64_t g = 0; g < n_groups; ++g) {
    T tmp[kVectors * L];
    for (int j = 0; j < kVectors; ++j)
      for (int64_t l = 0; l < L; ++l) tmp[j * L + l] = acc[g][j][l];
    std::copy(tmp, tmp + n_out, out + g * out_stride);
  }
}

template <typename T, class P>
void scatter_forward(const P& pol, const T* x, const T* param, const T* norm, T* y, int64_t B,
                     int64_t C, int64_t H, int64_t W, int nthreads) {
  const int64_t half = pol.half;
  const int64_t K = 2 * half + 1;
  const int64_t rpb = rows_per_block(B, H, nthreads);
  const int64_t blocks_per_image = (H + rpb - 1) / rpb;
  const int64_t plane = H * W;
  const int64_t nw = pol.rows();
  constexpr int G = 4;
#pragma omp parallel num_threads(nthreads)
  {
    RowRing<T> ring(K, half, W, nw + C);  // each slot: the weight rows, then C rows of x * norm
    std::vector<const T*> w_rows(K), xn_rows(K * G);
#pragma omp for schedule(dynamic, 1)
    for (int64_t block = 0; block < B * blocks_per_image; ++block) {
      const int64_t b = block / blocks_per_image;
      const int64_t y0 = (block % blocks_per_image) * rpb;
      const int64_t y1 = std::min(H, y0 + rpb);
      ring.reset();
      for (int64_t oy = y0; oy < y1; ++oy) {
        std::vector<T*> slots(K, nullptr);
        for (int64_t k = 0; k < K; ++k) {
          const int64_t sy = oy - (k - half);
          if (sy < 0 || sy >= H) continue;
          bool fresh;
          T* slot = ring.slot(sy, &fresh);
          if (fresh) {
            pol.fill_rows(param + b * plane + sy * W, W, slot + half, ring.padded);
            const T* nrow = norm + b * plane + sy * W;
            for (int64_t c = 0; c < C; ++c) {
              const T* xrow = x + (b * C + c) * plane + sy * W;
              T* dst = slot + (nw + c) * ring.padded + half;
              for (int64_t s = 0; s < W; ++s) dst[s] = xrow[s] * nrow[s];
            }
          }
          slots[k] = slot;
        }
        for (int64_t c0 = 0; c0 < C; c0 += G) {
          const int64_t gsize = std::min<int64_t>(G, C - c0);
          for (int64_t k = 0; k < K; ++k) {
            w_rows[k] = slots[k];
            for (int64_t g = 0; g < G; ++g)  // unused lanes of a short group read channel c0
              xn_rows[k * G + g] = slots[k] == nullptr ? nullptr
                  : slots[k] + (nw + c0 + std::min(g, gsize - 1)) * ring.padded;
          }
          for (int64_t x0 = 0; x0 < W; x0 += block_lanes<T>()) {
            scatter_forward_group<T, G>(pol, xn_rows.data(), w_rows.data(), ring.padded, x0,
                                        y + (b * C + c0) * plane + oy * W + x0, plane,
                                        std::min(block_lanes<T>(), W - x0), gsize);
          }
        }
      }
    }
  }
}

// Backward for G channels of one source row (weight rows w_row), one register block from source
// pixel s0.
template <typename T, int G, class P>
void scatter_backward_group(const P& pol, const T* w_row, int64_t padded, const T* const* g_rows,
                            int64_t s0, const T* x_row, int64_t x_stride, T* dx_row, T* m_row,
                            int64_t n_out, int64_t n_groups) {
  constexpr int64_t L = Vec<T>::lanes;
  const int64_t half = pol.half;
  V<T> acc_d[G][kVectors], acc_f[G][kVectors];
  for (int g = 0; g < G; ++g)
    for (int j = 0; j < kVectors; ++j) acc_d[g][j] = acc_f[g][j] = V<T>{};
  const int64_t K = 2 * half + 1;
  for (int64_t k = 0; k < K; ++k) {  // output row sy + dy
    const T* const* gr = g_rows + k * G;
    if (gr[0] == nullptr) continue;
    const int64_t dy = k - half;
    for (int64_t dx = -half; dx <= half; ++dx) {
      const int64_t base = half + s0 + dx;
      for (int j = 0; j < kVectors; ++j) {
        V<T> w, dw;
        pol.weights(w_row, padded, dy, dx, half + s0 + j * L, &w, &dw);
        for (int g = 0; g < G; ++g) {
          const V<T> gv = load(gr[g] + base + j * L);
          acc_d[g][j] += w * gv;
          acc_f[g][j] += dw * gv;
        }
      }
    }
  }
  for (int64_t g = 0; g < n_groups; ++g) {
    const T* xr = x_row + g * x_stride;
    for (int j = 0; j < kVectors; ++j)
      for (int64_t l = 0; l < L; ++l) {
        const int64_t i = j * L + l;
        if (i >= n_out) break;
        dx_row[g * x_stride + i] = acc_d[g][j][l];
        m_row[i] += xr[i] * acc_f[g][j][l];
      }
  }
}

template <typename T, class P>
void scatter_backward(const P& pol, const T* g, const T* x, const T* param, T* dx_raw, T* m,
                      int64_t B, int64_t C, int64_t H, int64_t W, int nthreads) {
  const int64_t half = pol.half;
  const int64_t K = 2 * half + 1;
  const int64_t rpb = rows_per_block(B, H, nthreads);
  const int64_t blocks_per_image = (H + rpb - 1) / rpb;
  const int64_t plane = H * W;
  constexpr int G = 2;
#pragma omp parallel num_threads(nthreads)
  {
    RowRing<T> ring(K, half, W, C);  // padded gradient rows
    RowRing<T> own(1, half, W, pol.rows());  // the source row's weight rows
    std::vector<const T*> g_rows(K * G);
#pragma omp for schedule(dynamic, 1)
    for (int64_t block = 0; block < B * blocks_per_image; ++block) {
      const int64_t b = block / blocks_per_image;
      const int64_t y0 = (block % blocks_per_image) * rpb;
      const int64_t y1 = std::min(H, y0 + rpb);
      ring.reset();
      for (int64_t sy = y0; sy < y1; ++sy) {
        bool fresh;
        T* wrow = own.slot(0, &fresh);
        pol.fill_rows(param + b * plane + sy * W, W, wrow + half, own.padded);
        std::vector<T*> slots(K, nullptr);
        for (int64_t k = 0; k < K; ++k) {
          const int64_t oy = sy + (k - half);
          if (oy < 0 || oy >= H) continue;
          T* slot = ring.slot(oy, &fresh);
          if (fresh)
            for (int64_t c = 0; c < C; ++c) {
              const T* grow = g + (b * C + c) * plane + oy * W;
              std::copy(grow, grow + W, slot + c * ring.padded + half);
            }
          slots[k] = slot;
        }
        T* mrow = m + b * plane + sy * W;
        std::fill(mrow, mrow + W, T(0));
        for (int64_t c0 = 0; c0 < C; c0 += G) {
          const int64_t gsize = std::min<int64_t>(G, C - c0);
          for (int64_t k = 0; k < K; ++k)
            for (int64_t gi = 0; gi < G; ++gi)
              g_rows[k * G + gi] = slots[k] == nullptr ? nullptr
                  : slots[k] + (c0 + std::min(gi, gsize - 1)) * ring.padded;
          for (int64_t s0 = 0; s0 < W; s0 += block_lanes<T>()) {
            const int64_t offset = (b * C + c0) * plane + sy * W + s0;
            scatter_backward_group<T, G>(pol, wrow, own.padded, g_rows.data(), s0, x + offset,
                                         plane, dx_raw + offset, mrow + s0,
                                         std::min(block_lanes<T>(), W - s0), gsize);
          }
        }
      }
    }
  }
}

// The policy's per-pixel window sums: the Gaussian's line(q) = sum_{d=-half..half} t_q(d) and
// moment(q) = sum_d d^2 t_q(d) (line^2 normalises a source to unit energy, moment is its
// sigma-derivative times sigma^3); the clamped distance's Z(q) and dZ/drho.
template <typename T, class P>
void window_sums(const P& pol, const T* param, T* first, T* second, int64_t n, int nthreads) {
  // A few flops per pixel: threads only pay off on large maps (waking them costs more).
  const int threads = n > (int64_t(1) << 20) ? nthreads : 1;
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int64_t i = 0; i < n; ++i) pol.sums(param[i], first + i, second + i);
}

// ---------------------------------------------------------------------------------------------
// Fused, normalised scatter (the renderer's "scatter" mode in one pass each way).
//
//   s_c(p) = sum_q norm_q w_q(p - q) X_c(q),  X = (x_0 .. x_{C-1}, 1),  norm_q = 1 / Z_q
//   y_c(p) = s_c(p) / s_C(p),  den(p) = s_C(p)
//
// The per-source parameter a_q (sigma for the Gaussian, rho for the clamped distance) gives the
// weights w_q and Z_q. Backward, from g = dL/dy:
//   G_c = g_c / den (c < C),  G_C = -sum_c g_c y_c / den      (dL/ds)
//   D_c(q) = sum_u w_q(u) G_c(q+u),  F_c(q) = sum_u dw_q(u)/da G_c(q+u)
//   dL/dx_c(q) = norm_q D_c(q)
//   dL/da_q = norm_q sum_c X_c F_c + (sum_c X_c D_c) dnorm/da
// The weight policies (above) give w, dw/da, Z and dnorm/da.

// Two output rows (oy, oy + 1) of G channels at once, one register block from output pixel x0:
// each source row and weight loaded serves both rows (they share K of their K + 1 source rows).
// Source row r of the K + 1 is sy = oy + 1 + half - r: offsets dy0 = oy - sy = r - half - 1 to row
// oy and dy0 + 1 to row oy + 1 (r = 0 reaches row oy + 1 only, r = K row oy only).
template <typename T, int G, class P>
void fused_forward_rows(const P& pol, const T* const* ch_rows, const T* const* w_rows,
                        int64_t padded, int64_t x0, T* const* out0, T* const* out1,
                        int64_t n_out, int64_t n_groups) {
  constexpr int64_t L = Vec<T>::lanes;
  constexpr int J = kRowVectors;
  const int64_t half = pol.half;
  V<T> acc0[G][J], acc1[G][J];
  for (int g = 0; g < G; ++g)
    for (int j = 0; j < J; ++j) acc0[g][j] = acc1[g][j] = V<T>{};
  const int64_t K = 2 * half + 1;
  for (int64_t r = 0; r <= K; ++r) {
    const T* wr = w_rows[r];
    if (wr == nullptr) continue;
    const int64_t dy0 = r - half - 1;
    const T* const* xr = ch_rows + r * G;
    const bool both = r >= 1 && r < K;
    if (both) {
      for (int64_t dx = -half; dx <= half; ++dx) {
        const int64_t base = x0 - dx + half;
        for (int j = 0; j < J; ++j) {
          V<T> w0, w1;
          pol.weight2(wr, padded, dy0, dx, base + j * L, &w0, &w1);
          for (int g = 0; g < G; ++g) {
            const V<T> v = load(xr[g] + base + j * L);
            acc0[g][j] += w0 * v;
            acc1[g][j] += w1 * v;
          }
        }
      }
    } else {
      const bool first = r == K;
      const int64_t dy = first ? dy0 : dy0 + 1;
      for (int64_t dx = -half; dx <= half; ++dx) {
        const int64_t base = x0 - dx + half;
        for (int j = 0; j < J; ++j) {
          const V<T> w = pol.weight(wr, padded, dy, dx, base + j * L);
          for (int g = 0; g < G; ++g) {
            const V<T> v = load(xr[g] + base + j * L);
            if (first)
              acc0[g][j] += w * v;
            else
              acc1[g][j] += w * v;
          }
        }
      }
    }
  }
  for (int64_t g = 0; g < n_groups; ++g) {
    T tmp[J * L];
    for (int j = 0; j < J; ++j)
      for (int64_t l = 0; l < L; ++l) tmp[j * L + l] = acc0[g][j][l];
    std::copy(tmp, tmp + n_out, out0[g] + x0);
    if (out1[g] == nullptr) continue;
    for (int j = 0; j < J; ++j)
      for (int64_t l = 0; l < L; ++l) tmp[j * L + l] = acc1[g][j][l];
    std::copy(tmp, tmp + n_out, out1[g] + x0);
  }
}

// Per-thread state of the forward passes that take two output rows (oy, oy + 1) at a time
// (fused_forward, layered_forward): a ring of the K + 1 source rows they reach, each slot its
// weight rows, `planes` rows of weighted channels (the last the norm row), and the row pointers
// of fused_forward_rows for groups of up to `group` channels.
template <typename T, class P>
struct TwoRowForward {
  const P& pol;
  int64_t half, K, nw, H, W, plane, planes;
  RowRing<T> ring;
  std::vector<T> scratch;
  std::vector<const T*> w_rows, ch_rows;
  std::vector<T*> out0, out1, slots;
  int64_t b = 0, oy = 0;
  bool pair = false;

  // Inlined into two_row_forward: GCC then knows the ring and the scratch row apart and vectorizes
  // the policy's fill (left scalar otherwise).
  __attribute__((always_inline)) TwoRowForward(const P& pol_, int64_t H_, int64_t W_,
                                               int64_t planes_, int64_t group)
      : pol(pol_), half(pol_.half), K(2 * pol_.half + 1), nw(pol_.rows()), H(H_), W(W_),
        plane(H_ * W_), planes(planes_), ring(K + 1, half, W, nw + planes), scratch(4 * W + 1),
        w_rows(K + 1), ch_rows((K + 1) * group), out0(group), out1(group), slots(K + 1) {}

  // Row plane p of a slot (index half + s is pixel s).
  T* row(T* slot, int64_t p) const { return slot + (nw + p) * ring.padded + half; }
  // Point slots at the ring rows of the source rows reached (source row r of the K + 1 is
  // sy = oy + 1 + half - r, see fused_forward_rows), filling the weight and norm rows of those
  // new to the ring and then fill(slot, sy, norm) the rest of them.
  template <class Fill>
  void gather(const T* param, const Fill& fill) {
    for (int64_t r = 0; r <= K; ++r) {
      const int64_t sy = oy + 1 + half - r;
      slots[r] = nullptr;
      if (sy < 0 || sy >= H || (!pair && r == 0)) continue;
      bool fresh;
      T* slot = ring.slot(sy, &fresh);
      if (fresh) {
        fill_weights(param + b * plane + sy * W, slot);
        fill(slot, sy, static_cast<const T*>(row(slot, planes - 1)));
      }
      slots[r] = slot;
    }
  }
  // A slot's weight rows and norm row from its row of the parameter.
  void fill_weights(const T* param_row, T* slot) {
    pol.fill(param_row, W, slot + half, ring.padded, row(slot, planes - 1), nullptr,
             scratch.data());
  }
  template <int G>
  void run(int64_t x0, int64_t n_out, int64_t gsize) {
    fused_forward_rows<T, G, P>(pol, ch_rows.data(), w_rows.data(), ring.padded, x0,
                                out0.data(), out1.data(), n_out, gsize);
  }
};

// Row blocks of every image split across the threads; in each, the output rows two at a time
// (the last alone in a block of odd height): step(st) on the thread's state st, set on them.
// make_step() gives each thread its step (a lambda owning the thread's other buffers).
template <typename T, class P, class MakeStep>
void two_row_forward(const P& pol, int64_t B, int64_t H, int64_t W, int64_t planes,
                     int64_t group, int nthreads, const MakeStep& make_step) {
  const int64_t rpb = rows_per_block(B, H, nthreads);
  const int64_t blocks_per_image = (H + rpb - 1) / rpb;
#pragma omp parallel num_threads(nthreads)
  {
    TwoRowForward<T, P> st(pol, H, W, planes, group);
    auto step = make_step();
#pragma omp for schedule(dynamic, 1)
    for (int64_t block = 0; block < B * blocks_per_image; ++block) {
      st.b = block / blocks_per_image;
      const int64_t y0 = (block % blocks_per_image) * rpb;
      const int64_t y1 = std::min(H, y0 + rpb);
      st.ring.reset();
      for (int64_t oy = y0; oy < y1; oy += 2) {
        st.oy = oy;
        st.pair = oy + 1 < y1;
        step(st);
      }
    }
  }
}

template <typename T, class P>
void fused_forward(const P& pol, const T* x, const T* param, T* y, T* den, int64_t B, int64_t C,
                   int64_t H, int64_t W, int nthreads) {
  const int64_t plane = H * W;
  const int64_t C1 = C + 1;
  constexpr int G = 4;
  constexpr int64_t lanes = kRowVectors * Vec<T>::lanes;
  // slot planes: C rows of x * norm, the norm row
  two_row_forward<T>(pol, B, H, W, C1, G, nthreads, [&] {
    return [&](TwoRowForward<T, P>& st) {
      const int64_t b = st.b, oy = st.oy;
      const bool pair = st.pair;
      st.gather(param, [&](T* slot, int64_t sy, const T* norm) {
        for (int64_t c = 0; c < C; ++c) {
          const T* xrow = x + (b * C + c) * plane + sy * W;
          T* dst = st.row(slot, c);
          for (int64_t s = 0; s < W; ++s) dst[s] = xrow[s] * norm[s];
        }
      });
      T* den0 = den + b * plane + oy * W;
      T* den1 = pair ? den0 + W : nullptr;
      for (int64_t c0 = 0; c0 < C1; c0 += G) {
        const int64_t gsize = std::min<int64_t>(G, C1 - c0);
        for (int64_t r = 0; r <= st.K; ++r) {
          st.w_rows[r] = st.slots[r];
          for (int64_t g = 0; g < G; ++g)
            st.ch_rows[r * G + g] = st.slots[r] == nullptr ? nullptr
                : st.slots[r] + (st.nw + c0 + std::min<int64_t>(g, gsize - 1)) * st.ring.padded;
        }
        for (int64_t g = 0; g < gsize; ++g) {
          const int64_t c = c0 + g;
          st.out0[g] = c < C ? y + (b * C + c) * plane + oy * W : den0;
          st.out1[g] = !pair ? nullptr : c < C ? st.out0[g] + W : den1;
        }
        for (int64_t x0 = 0; x0 < W; x0 += lanes)
          st.template run<G>(x0, std::min(lanes, W - x0), gsize);
      }
      for (int64_t c = 0; c < C; ++c) {
        T* yr = y + (b * C + c) * plane + oy * W;
        for (int64_t s = 0; s < W; ++s) yr[s] /= den0[s];
        if (pair)
          for (int64_t s = 0; s < W; ++s) yr[W + s] /= den1[s];
      }
    };
  });
}

// Two source rows (sy, sy + 1) of G channels at once, one register block from source pixel s0:
// each gradient load serves both rows (they share K of their K + 1 output rows). Output row r of
// the K + 1 is oy = sy - half + r: offsets dy0 = r - half from row sy, dy0 - 1 from row sy + 1.
template <typename T, int G, class P>
void fused_backward_rows(const P& pol, const T* w0_row, const T* w1_row, int64_t w_padded,
                         const T* const* g_rows, int64_t s0, const T* const* x_rows,
                         T* const* d0_rows, T* const* d1_rows, T* m0_row, T* m1_row,
                         int64_t n_out, int64_t n_groups) {
  const int64_t half = pol.half;
  V<T> d0[G], f0[G], d1[G], f1[G];
  for (int g = 0; g < G; ++g) d0[g] = f0[g] = d1[g] = f1[g] = V<T>{};
  const int64_t K = 2 * half + 1;
  const int64_t idx = half + s0;
  for (int64_t r = 0; r <= K; ++r) {
    const T* const* gr = g_rows + r * G;
    if (gr[0] == nullptr) continue;
    const int64_t dy0 = r - half;
    const bool first = r < K, second = r > 0 && w1_row != nullptr;
    for (int64_t dx = -half; dx <= half; ++dx) {
      const int64_t base = idx + dx;
      V<T> gv[G];
      for (int g = 0; g < G; ++g) gv[g] = load(gr[g] + base);
      if (first) {
        V<T> w, dw;
        pol.weights(w0_row, w_padded, dy0, dx, idx, &w, &dw);
        for (int g = 0; g < G; ++g) {
          d0[g] += w * gv[g];
          f0[g] += dw * gv[g];
        }
      }
      if (second) {
        V<T> w, dw;
        pol.weights(w1_row, w_padded, dy0 - 1, dx, idx, &w, &dw);
        for (int g = 0; g < G; ++g) {
          d1[g] += w * gv[g];
          f1[g] += dw * gv[g];
        }
      }
    }
  }
  for (int64_t g = 0; g < n_groups; ++g) {
    const T* xr0 = x_rows[g] + s0;
    T* dr0 = d0_rows[g] + s0;
    for (int64_t i = 0; i < n_out; ++i) {
      dr0[i] = d0[g][i];
      m0_row[i] += xr0[i] * f0[g][i];
    }
    if (w1_row == nullptr) continue;
    const T* xr1 = x_rows[G + g] + s0;
    T* dr1 = d1_rows[g] + s0;
    for (int64_t i = 0; i < n_out; ++i) {
      dr1[i] = d1[g][i];
      m1_row[i] += xr1[i] * f1[g][i];
    }
  }
}

// Per-thread state of the backward passes that take two source rows (sy, sy + 1) at a time
// (fused_backward, layered_backward): a ring of padded gradient rows (`planes` rows a slot) for
// the K + 1 output rows the two source rows reach, the source rows' weight rows, norm and dnorm,
// their D rows (`planes` each) and moment rows, and the row pointers of fused_backward_rows.
template <typename T, class P>
struct TwoRowBackward {
  static constexpr int G = 4;
  const P& pol;
  int64_t half, K, nw, H, W, plane, stride, planes;
  RowRing<T> ring;
  RowRing<T> own;
  std::vector<T> dbuf, mrow, scratch;
  std::vector<const T*> g_rows, x_rows;
  std::vector<T*> d0_rows, d1_rows, slots;
  T* wslot[2] = {nullptr, nullptr};
  int64_t b = 0, sy = 0;
  bool pair = false;

  TwoRowBackward(const P& pol_, int64_t H_, int64_t W_, int64_t planes_)
      : pol(pol_), half(pol_.half), K(2 * pol_.half + 1), nw(pol_.rows()), H(H_), W(W_),
        plane(H_ * W_), stride(W_ + kPadRight), planes(planes_), ring(K + 1, half, W, planes),
        own(2, half, W, nw + 2), dbuf(2 * planes * stride), mrow(2 * stride), scratch(4 * W + 1),
        g_rows((K + 1) * G), x_rows(2 * G), d0_rows(G), d1_rows(G), slots(K + 1) {}

  int64_t rows() const { return pair ? 2 : 1; }
  const T* norm(int64_t i) const { return wslot[i] + nw * own.padded + half; }
  const T* dnorm(int64_t i) const { return wslot[i] + (nw + 1) * own.padded + half; }
  const T* d(int64_t i) const { return dbuf.data() + i * planes * stride; }
  const T* m(int64_t i) const { return mrow.data() + i * stride; }

  // Rows sy and sy + 1 (sy alone unless pair) of image b: their weight rows, norm and dnorm.
  void start(const T* param, int64_t b_, int64_t sy_, bool pair_) {
    b = b_;
    sy = sy_;
    pair = pair_;
    for (int64_t i = 0; i < rows(); ++i) {
      bool fresh;
      wslot[i] = own.slot(i, &fresh);
      pol.fill(param + b * plane + (sy + i) * W, W, wslot[i] + half, own.padded,
               wslot[i] + nw * own.padded + half, wslot[i] + (nw + 1) * own.padded + half,
               scratch.data());
    }
  }
  // Point slots at the ring rows of the output rows reached, fill(slot, oy) filling those new to
  // the ring; clear the moment rows.
  template <class Fill>
  void gather(const Fill& fill) {
    for (int64_t r = 0; r <= K; ++r) {
      const int64_t oy = sy - half + r;
      slots[r] = nullptr;
      if (oy < 0 || oy >= H || (!pair && r == K)) continue;
      bool fresh;
      T* slot = ring.slot(oy, &fresh);
      if (fresh) fill(slot, oy);
      slots[r] = slot;
    }
    std::fill(mrow.begin(), mrow.end(), T(0));
  }
  // A group of gsize gradient planes from plane p0 (the last repeated up to G).
  void point_g(int64_t p0, int64_t gsize) {
    for (int64_t r = 0; r <= K; ++r)
      for (int64_t gi = 0; gi < G; ++gi)
        g_rows[r * G + gi] = slots[r] == nullptr ? nullptr
            : slots[r] + (p0 + std::min<int64_t>(gi, gsize - 1)) * ring.padded;
  }
  // Member gi of the group writes the D rows of plane p.
  void point_d(int64_t gi, int64_t p) {
    d0_rows[gi] = dbuf.data() + p * stride;
    d1_rows[gi] = dbuf.data() + (planes + p) * stride;
  }
  void run(int64_t s0, int64_t n_out, int64_t gsize) {
    fused_backward_rows<T, G, P>(pol, wslot[0], pair ? wslot[1] : nullptr, own.padded,
                                 g_rows.data(), s0, x_rows.data(), d0_rows.data(),
                                 d1_rows.data(), mrow.data() + s0, mrow.data() + stride + s0,
                                 n_out, gsize);
  }
};

// Row blocks of every image split across the threads; in each, the source rows two at a time
// (the last alone in a block of odd height): step(st) on the thread's state st, started on them.
// make_step() gives each thread its step (a lambda owning the thread's other buffers).
template <typename T, class P, class MakeStep>
void two_row_backward(const P& pol, const T* param, int64_t B, int64_t H, int64_t W,
                      int64_t planes, int nthreads, const MakeStep& make_step) {
  const int64_t rpb = rows_per_block(B, H, nthreads);
  const int64_t blocks_per_image = (H + rpb - 1) / rpb;
#pragma omp parallel num_threads(nthreads)
  {
    TwoRowBackward<T, P> st(pol, H, W, planes);
    auto step = make_step();
#pragma omp for schedule(dynamic, 1)
    for (int64_t block = 0; block < B * blocks_per_image; ++block) {
      const int64_t b = block / blocks_per_image;
      const int64_t y0 = (block % blocks_per_image) * rpb;
      const int64_t y1 = std::min(H, y0 + rpb);
      st.ring.reset();
      for (int64_t sy = y0; sy < y1; sy += 2) {
        st.start(param, b, sy, sy + 1 < y1);
        step(st);
      }
    }
  }
}

template <typename T, class P>
void fused_backward(const P& pol, const T* g, const T* y, const T* den, const T* x,
                    const T* param, T* grad_x, T* grad_param, int64_t B, int64_t C, int64_t H,
                    int64_t W, int nthreads) {
  const int64_t plane = H * W;
  const int64_t C1 = C + 1;
  const int64_t stride = W + kPadRight;
  constexpr int G = TwoRowBackward<T, P>::G;
  constexpr int64_t lanes = Vec<T>::lanes;
  // ring rows: G = dL/ds; D rows: D_c
  two_row_backward<T>(pol, param, B, H, W, C1, nthreads, [&] {
    return [&, ones = std::vector<T>(stride, T(1))](TwoRowBackward<T, P>& st) {
      const int64_t b = st.b, sy = st.sy;
      st.gather([&](T* slot, int64_t oy) {
        const T* drow = den + b * plane + oy * W;
        T* last = slot + C * st.ring.padded + st.half;
        std::fill(last, last + W, T(0));
        for (int64_t c = 0; c < C; ++c) {
          const T* grow = g + (b * C + c) * plane + oy * W;
          const T* yrow = y + (b * C + c) * plane + oy * W;
          T* dst = slot + c * st.ring.padded + st.half;
          for (int64_t s = 0; s < W; ++s) {
            const T gd = grow[s] / drow[s];
            dst[s] = gd;
            last[s] -= gd * yrow[s];
          }
        }
      });
      for (int64_t c0 = 0; c0 < C1; c0 += G) {
        const int64_t gsize = std::min<int64_t>(G, C1 - c0);
        st.point_g(c0, gsize);
        for (int64_t gi = 0; gi < gsize; ++gi) {
          const int64_t c = c0 + gi;
          for (int64_t i = 0; i < 2; ++i)
            st.x_rows[i * G + gi] = c < C ? x + (b * C + c) * plane + (sy + i) * W : ones.data();
          st.point_d(gi, c);
        }
        for (int64_t s0 = 0; s0 < W; s0 += lanes)
          st.run(s0, std::min<int64_t>(lanes, W - s0), gsize);
      }
      for (int64_t i = 0; i < st.rows(); ++i) {
        const int64_t row = sy + i;
        const T* norm = st.norm(i);
        const T* dnorm = st.dnorm(i);
        const T* d = st.d(i);
        const T* m = st.m(i);
        const T* prow = param + b * plane + row * W;
        T* gp = grad_param + b * plane + row * W;
        const T* dlast = d + C * stride;
        for (int64_t s = 0; s < W; ++s) gp[s] = dlast[s];  // sum_c X_c D_c, X_C = 1
        for (int64_t c = 0; c < C; ++c) {
          const T* xrow = x + (b * C + c) * plane + row * W;
          const T* dc = d + c * stride;
          T* gx = grad_x + (b * C + c) * plane + row * W;
          for (int64_t s = 0; s < W; ++s) {
            gx[s] = norm[s] * dc[s];
            gp[s] += xrow[s] * dc[s];
          }
        }
        for (int64_t s = 0; s < W; ++s)
          gp[s] = norm[s] * m[s] * pol.scale(prow[s]) + gp[s] * dnorm[s];
      }
    };
  });
}


// Ask for transparent huge pages on the 2 MiB-aligned interior of a large output not yet written
// (a fresh mapping: first touching 4 KiB pages costs more than the layered forward's arithmetic).
inline void advise_huge_pages(void* data, int64_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr uintptr_t huge = uintptr_t(1) << 21;
  const uintptr_t start = (reinterpret_cast<uintptr_t>(data) + huge - 1) & ~(huge - 1);
  const uintptr_t end = (reinterpret_cast<uintptr_t>(data) + bytes) & ~(huge - 1);
  if (end > start) madvise(reinterpret_cast<void*>(start), end - start, MADV_HUGEPAGE);
#else
  (void)data;
  (void)bytes;
#endif
}

// ---------------------------------------------------------------------------------------------
// Layered (occlusion-aware) mode in one pass each way. Layer weights from the continuous layer
// position pos_q in [0, L-1]: alpha_l(q) = max(0, 1 - |pos_q - l|) (two layers per pixel at most).
//
//   S_{l,c}(p) = sum_q norm_q w_q(p - q) alpha_l(q) X_c(q),  X = (x_0 .. x_{C-1}, 1)
//   T_0 = 1, T_{l+1} = T_l (1 - min(S_{l,C}, 1)),  out_c = sum_l T_l S_{l,c} / max(sum_l T_l S_{l,C}, tiny)
//
// Work is skipped where it is exactly zero: a layer absent from every source of a register
// block's window (forward), or whose weight has a zero derivative at every source of the block
// (backward: |pos_q - l| > 1), so the cost follows the number of layers present locally. S is
// written, composited and read back only on the rows of the layers present nearby (window_layers).
template <typename T>
inline T layer_alpha(T p, int64_t l) {
  const T a = T(1) - std::abs(p - T(l));
  return a > T(0) ? a : T(0);
}

template <typename T>
inline uint32_t layer_bits(T p, int64_t n_layers, bool inclusive) {
  // Layers l with alpha_l(p) != 0 (|p - l| < 1: floor(p), and floor(p) + 1 unless p is whole), or
  // with |p - l| <= 1 when inclusive (also floor(p) + 1, and floor(p) - 1 when p is whole).
  const int64_t fl = static_cast<int64_t>(p);  // p >= 0
  const bool whole = T(fl) == p;
  uint32_t bits = uint32_t(1) << fl;
  if (!whole || inclusive) bits |= uint32_t(2) << fl;
  if (inclusive && whole && fl > 0) bits |= uint32_t(1) << (fl - 1);
  return n_layers >= 32 ? bits : bits & ((uint32_t(1) << n_layers) - 1);
}

// Per row y of each image, (B, H): the layers of the sources within `reach` rows (layer_bits,
// `inclusive` or not, of all their pixels). With reach = half and exclusive bits, S_{l,.}(y) is
// exactly zero for the layers outside: those spread rows are neither written nor read.
template <typename T>
std::vector<uint32_t> window_layers(const T* pos, int64_t B, int64_t H, int64_t W, int64_t NL,
                                    int64_t reach, bool inclusive) {
  std::vector<uint32_t> own(B * H, 0u), near(B * H, 0u);
  for (int64_t r = 0; r < B * H; ++r)
    for (int64_t s = 0; s < W; ++s) own[r] |= layer_bits(pos[r * W + s], NL, inclusive);
  for (int64_t b = 0; b < B; ++b)
    for (int64_t y = 0; y < H; ++y)
      for (int64_t sy = std::max<int64_t>(0, y - reach); sy <= std::min(H - 1, y + reach); ++sy)
        near[b * H + y] |= own[b * H + sy];
  return near;
}

template <typename T>
void composite_row(const T* S, T* out, int64_t C, int64_t NL, int64_t plane, int64_t W, int64_t b,
                   int64_t row, uint32_t present, T* work) {
  const int64_t C1 = C + 1;
  const T tiny = std::numeric_limits<T>::min();
  T* t = work;
  T* cov = work + W;
  T* colour = work + 2 * W;
  std::fill(t, t + W, T(1));
  std::fill(cov, cov + W, T(0));
  std::fill(colour, colour + C * W, T(0));
  for (int64_t l = 0; l < NL; ++l) {
    if (!((present >> l) & 1u)) continue;  // S_l = 0 here: nothing to add, T unchanged
    const T* a = S + ((b * NL + l) * C1 + C) * plane + row * W;
    for (int64_t c = 0; c < C; ++c) {
      const T* sc = S + ((b * NL + l) * C1 + c) * plane + row * W;
      T* col = colour + c * W;
      for (int64_t s = 0; s < W; ++s) col[s] = col[s] + t[s] * sc[s];
    }
    for (int64_t s = 0; s < W; ++s) {
      cov[s] = cov[s] + t[s] * a[s];
      t[s] = t[s] * (T(1) - std::min(a[s], T(1)));
    }
  }
  for (int64_t s = 0; s < W; ++s) cov[s] = std::max(cov[s], tiny);
  for (int64_t c = 0; c < C; ++c) {
    T* o = out + (b * C + c) * plane + row * W;
    const T* col = colour + c * W;
    for (int64_t s = 0; s < W; ++s) o[s] = col[s] / cov[s];
  }
}

template <typename T, class P>
void layered_forward(const P& pol, const T* x, const T* pos, const T* param, T* S, T* out,
                     int64_t B, int64_t C, int64_t H, int64_t W, int64_t NL, int nthreads) {
  const int64_t half = pol.half;
  const int64_t K = 2 * half + 1;
  const int64_t plane = H * W;
  const int64_t C1 = C + 1;
  const int64_t LC = NL * C1;
  constexpr int G = 4;
  constexpr int G2 = 8;
  constexpr int64_t lanes = kRowVectors * Vec<T>::lanes;
  const int64_t ntiles = (W + lanes - 1) / lanes;
  advise_huge_pages(S, B * LC * plane * static_cast<int64_t>(sizeof(T)));
  const std::vector<uint32_t> present = window_layers(pos, B, H, W, NL, half, false);
  // slot planes: L (C + 1) rows of alpha_l X_c norm, the norm row
  two_row_forward<T>(pol, B, H, W, LC + 1, G2, nthreads, [&] {
    return [&, tile_mask = std::vector<uint32_t>((K + 1) * ntiles),
            row_mask = std::vector<uint32_t>(K + 1), window_mask = std::vector<uint32_t>(K + 1),
            slot_index = std::vector<int64_t>(K + 1), chan = std::vector<int64_t>(LC),
            work = std::vector<T>((C + 2) * W),
            zero_row = std::vector<T>(W + 2 * half + kPadRight, T(0)),
            discard = std::vector<T>(W)](TwoRowForward<T, P>& st) mutable {
      const int64_t b = st.b, oy = st.oy;
      const bool pair = st.pair;
      const int64_t nw = st.nw, padded = st.ring.padded;
      // the spread rows written: those of the layers present within half rows (the rest are 0)
      const uint32_t rows_present[2] = {present[b * H + oy], pair ? present[b * H + oy + 1] : 0u};
      st.gather(param, [&](T* slot, int64_t sy, const T* norm) {
        const int64_t k = sy % (K + 1);
        const T* prow = pos + b * plane + sy * W;
        uint32_t rm = 0;
        for (int64_t t = 0; t < ntiles; ++t) {
          uint32_t m = 0;
          for (int64_t s = t * lanes; s < std::min(W, (t + 1) * lanes); ++s)
            m |= layer_bits(prow[s], NL, false);
          tile_mask[k * ntiles + t] = m;
          rm |= m;
        }
        row_mask[k] = rm;
        for (int64_t l = 0; l < NL; ++l) {
          if (!((rm >> l) & 1u)) continue;  // never read: the row pointer is null then
          T* last = st.row(slot, l * C1 + C);
          for (int64_t s = 0; s < W; ++s) last[s] = layer_alpha(prow[s], l) * norm[s];
          for (int64_t c = 0; c < C; ++c) {
            const T* xrow = x + (b * C + c) * plane + sy * W;
            T* dst = st.row(slot, l * C1 + c);
            for (int64_t s = 0; s < W; ++s) dst[s] = last[s] * xrow[s];
          }
        }
      });
      for (int64_t r = 0; r <= K; ++r) slot_index[r] = (oy + 1 + half - r) % (K + 1);
      for (int64_t x0 = 0; x0 < W; x0 += lanes) {
        const int64_t n_out = std::min(lanes, W - x0);
        const int64_t t0 = std::max<int64_t>(0, x0 - half) / lanes;
        const int64_t t1 = std::min(ntiles - 1, (x0 + lanes - 1 + half) / lanes);
        uint32_t bm = 0;
        for (int64_t r = 0; r <= K; ++r) {
          window_mask[r] = 0;
          if (st.slots[r] == nullptr) continue;
          const uint32_t* tm = tile_mask.data() + slot_index[r] * ntiles;
          for (int64_t t = t0; t <= t1; ++t) window_mask[r] |= tm[t];
          bm |= window_mask[r];
        }
        // The channels of the layers present, in groups of up to G2: the weights of a tap
        // are computed once for all of them.
        int64_t n_ch = 0;
        for (int64_t l = 0; l < NL; ++l) {
          if ((bm >> l) & 1u) {
            for (int64_t c = 0; c < C1; ++c) chan[n_ch++] = l * C1 + c;
            continue;
          }
          for (int64_t i = 0; i < 2; ++i) {
            if (!((rows_present[i] >> l) & 1u)) continue;
            for (int64_t c = 0; c < C1; ++c) {
              T* o = S + ((b * NL + l) * C1 + c) * plane + (oy + i) * W + x0;
              std::fill(o, o + n_out, T(0));
            }
          }
        }
        for (int64_t i0 = 0; i0 < n_ch; i0 += G2) {
          const int64_t gsize = std::min<int64_t>(G2, n_ch - i0);
          const int64_t G_used = gsize > G ? G2 : G;
          for (int64_t r = 0; r <= K; ++r) {
            bool any = false;
            for (int64_t g = 0; g < G_used; ++g) {
              const int64_t lc = chan[i0 + std::min(g, gsize - 1)];
              // a row whose sources in this block's window all lack the layer adds nothing
              const bool has = st.slots[r] != nullptr && ((window_mask[r] >> (lc / C1)) & 1u);
              st.ch_rows[r * G_used + g] = has ? st.slots[r] + (nw + lc) * padded : zero_row.data();
              any = any || has;
            }
            st.w_rows[r] = any ? st.slots[r] : nullptr;
          }
          for (int64_t g = 0; g < gsize; ++g) {
            const int64_t l = chan[i0 + g] / C1;
            T* row0 = S + (b * LC + chan[i0 + g]) * plane + oy * W;
            st.out0[g] = (rows_present[0] >> l) & 1u ? row0 : discard.data();
            st.out1[g] = (rows_present[1] >> l) & 1u ? row0 + W : nullptr;
          }
          if (G_used == G2)
            st.template run<G2>(x0, n_out, gsize);
          else
            st.template run<G>(x0, n_out, gsize);
        }
      }
      composite_row<T>(S, out, C, NL, plane, W, b, oy, rows_present[0], work.data());
      if (pair) composite_row<T>(S, out, C, NL, plane, W, b, oy + 1, rows_present[1], work.data());
    };
  });
}

// dL/dS of the compositing along one output row, written into the ring slot's rows of the layers
// `reached` (the only ones read); S is read for the layers `present` (zero for the others, which
// leave T and dL/dT unchanged). work: (NL + C + 5) rows of W values.
template <typename T>
void composite_backward_row(const T* g, const T* out, const T* S, T* slot, int64_t padded,
                            int64_t half, int64_t C, int64_t NL, int64_t plane, int64_t W,
                            int64_t b, int64_t row, uint32_t present, uint32_t reached,
                            T* work) {
  const int64_t C1 = C + 1;
  const T tiny = std::numeric_limits<T>::min();
  T* tl = work;                    // T_l, NL rows
  T* cov = work + NL * W;
  T* dcov = cov + W;
  T* dt = dcov + W;                // dL/dT_{l+1} while going back
  T* dtl = dt + W;
  T* dcol = dtl + W;               // C rows: g_c / max(cov, tiny)
  T* zeros = dcol + C * W;
  std::fill(zeros, zeros + W, T(0));
  const int64_t at = row * W;
  std::fill(tl, tl + W, T(1));
  std::fill(cov, cov + W, T(0));
  for (int64_t l = 0; l < NL; ++l) {
    const T* a = S + ((b * NL + l) * C1 + C) * plane + at;
    T* t = tl + l * W;
    if (!((present >> l) & 1u)) {
      if (l + 1 < NL) std::copy(t, t + W, t + W);
      continue;
    }
    for (int64_t s = 0; s < W; ++s) cov[s] = cov[s] + t[s] * a[s];
    if (l + 1 < NL)
      for (int64_t s = 0; s < W; ++s) t[W + s] = t[s] * (T(1) - std::min(a[s], T(1)));
  }
  std::fill(dcov, dcov + W, T(0));
  for (int64_t c = 0; c < C; ++c) {
    const T* gc = g + (b * C + c) * plane + at;
    const T* oc = out + (b * C + c) * plane + at;
    T* dc = dcol + c * W;
    for (int64_t s = 0; s < W; ++s) {
      const T denom = std::max(cov[s], tiny);
      dc[s] = gc[s] / denom;
      dcov[s] -= gc[s] * oc[s];
    }
  }
  for (int64_t s = 0; s < W; ++s)
    dcov[s] = cov[s] >= tiny ? dcov[s] / std::max(cov[s], tiny) : T(0);
  std::fill(dt, dt + W, T(0));
  for (int64_t l = NL - 1; l >= 0; --l) {
    if (!((reached >> l) & 1u)) continue;  // then not present either: dL/dT unchanged
    const bool has = (present >> l) & 1u;   // else S_l = 0, read from the zero row
    const T* a = has ? S + ((b * NL + l) * C1 + C) * plane + at : zeros;
    const T* t = tl + l * W;
    for (int64_t s = 0; s < W; ++s) dtl[s] = a[s] * dcov[s] + dt[s] * (T(1) - std::min(a[s], T(1)));
    for (int64_t c = 0; c < C; ++c) {
      const T* sc = has ? S + ((b * NL + l) * C1 + c) * plane + at : zeros;
      const T* dc = dcol + c * W;
      T* gs = slot + (l * C1 + c) * padded + half;
      for (int64_t s = 0; s < W; ++s) {
        gs[s] = t[s] * dc[s];
        dtl[s] += sc[s] * dc[s];
      }
    }
    T* gs = slot + (l * C1 + C) * padded + half;
    for (int64_t s = 0; s < W; ++s)
      gs[s] = t[s] * dcov[s] - (a[s] <= T(1) ? dt[s] * t[s] : T(0));
    std::copy(dtl, dtl + W, dt);
  }
}

template <typename T, class P>
void layered_backward(const P& pol, const T* g, const T* out, const T* S, const T* x,
                      const T* pos, const T* param, T* grad_x, T* grad_pos, T* grad_param,
                      int64_t B, int64_t C, int64_t H, int64_t W, int64_t NL, int nthreads) {
  const int64_t half = pol.half;
  const int64_t plane = H * W;
  const int64_t C1 = C + 1;
  const int64_t LC = NL * C1;
  const int64_t stride = W + kPadRight;
  constexpr int G = TwoRowBackward<T, P>::G;
  constexpr int64_t lanes = Vec<T>::lanes;
  // The spread rows the forward wrote, and the dL/dS rows the register blocks read: those of the
  // layers reached (|pos - l| <= 1) by a source row sy or sy + 1 of the K + 1 output rows' pairs.
  const std::vector<uint32_t> present = window_layers(pos, B, H, W, NL, half, false);
  const std::vector<uint32_t> reached = window_layers(pos, B, H, W, NL, half + 1, true);
  // ring rows: dL/dS; D rows: D_{l,c}; xl: alpha_l X_c of the two source rows
  two_row_backward<T>(pol, param, B, H, W, LC, nthreads, [&] {
    return [&, xl = std::vector<T>(2 * LC * stride, T(0)),
            work = std::vector<T>((NL + C + 5) * W),
            acc = std::vector<T>(2 * W), bits = std::vector<uint32_t>(2 * W)](
               TwoRowBackward<T, P>& st) mutable {
      const int64_t b = st.b, sy = st.sy, rows = st.rows();
      const bool pair = st.pair;
      uint32_t row_support[2] = {0, 0};
      for (int64_t i = 0; i < 2; ++i) {  // a lone row's partner has no layer
        const T* prow = pos + b * plane + (sy + i) * W;
        uint32_t* bi = bits.data() + i * W;
        uint32_t support = 0;
        for (int64_t s = 0; s < W; ++s) {
          bi[s] = i < rows ? layer_bits(prow[s], NL, true) : 0u;
          support |= bi[s];
        }
        row_support[i] = support;
      }
      const uint32_t both_rows = row_support[0] | (pair ? row_support[1] : 0u);
      for (int64_t i = 0; i < rows; ++i) {
        const T* prow = pos + b * plane + (sy + i) * W;
        for (int64_t l = 0; l < NL; ++l) {
          // the register blocks read both rows' X for the layers of either: fill the union
          if (!((both_rows >> l) & 1u)) continue;
          T* last = xl.data() + (i * LC + l * C1 + C) * stride;
          for (int64_t s = 0; s < W; ++s) last[s] = layer_alpha(prow[s], l);
          for (int64_t c = 0; c < C; ++c) {
            const T* xrow = x + (b * C + c) * plane + (sy + i) * W;
            T* dst = xl.data() + (i * LC + l * C1 + c) * stride;
            for (int64_t s = 0; s < W; ++s) dst[s] = last[s] * xrow[s];
          }
        }
      }
      st.gather([&](T* slot, int64_t oy) {
        composite_backward_row<T>(g, out, S, slot, st.ring.padded, half, C, NL, plane, W, b, oy,
                                  present[b * H + oy], reached[b * H + oy], work.data());
      });
      for (int64_t s0 = 0; s0 < W; s0 += lanes) {
        const int64_t n_out = std::min<int64_t>(lanes, W - s0);
        uint32_t support = 0;
        for (int64_t s = s0; s < s0 + n_out; ++s) support |= bits[s] | bits[W + s];
        for (int64_t l = 0; l < NL; ++l) {
          if (!((both_rows >> l) & 1u)) continue;  // D never read (see row_support below)
          if (!((support >> l) & 1u)) {
            for (int64_t i = 0; i < 2 * LC; i += LC)
              for (int64_t c = 0; c < C1; ++c) {
                T* d = st.dbuf.data() + (i + l * C1 + c) * stride + s0;
                std::fill(d, d + n_out, T(0));
              }
            continue;
          }
          for (int64_t c0 = 0; c0 < C1; c0 += G) {
            const int64_t gsize = std::min<int64_t>(G, C1 - c0);
            st.point_g(l * C1 + c0, gsize);
            for (int64_t gi = 0; gi < gsize; ++gi) {
              const int64_t c = l * C1 + c0 + gi;
              st.x_rows[gi] = xl.data() + c * stride;
              st.x_rows[G + gi] = xl.data() + (LC + c) * stride;
              st.point_d(gi, c);
            }
            st.run(s0, n_out, gsize);
          }
        }
      }
      for (int64_t i = 0; i < rows; ++i) {
        const int64_t row = sy + i;
        const T* norm = st.norm(i);
        const T* dnorm = st.dnorm(i);
        const T* d = st.d(i);
        const T* xs = xl.data() + i * LC * stride;
        const T* m = st.m(i);
        const T* prow = param + b * plane + row * W;
        const T* qrow = pos + b * plane + row * W;
        T* gp = grad_param + b * plane + row * W;
        T* gq = grad_pos + b * plane + row * W;
        T* sum_xd = acc.data();
        T* dalpha = acc.data() + W;
        std::fill(sum_xd, sum_xd + W, T(0));
        std::fill(gq, gq + W, T(0));
        for (int64_t c = 0; c < C; ++c) {
          T* gx = grad_x + (b * C + c) * plane + row * W;
          std::fill(gx, gx + W, T(0));
        }
        for (int64_t l = 0; l < NL; ++l) {
          if (!((row_support[i] >> l) & 1u)) continue;  // D = 0 and d alpha / d pos = 0
          const T* al = xs + (l * C1 + C) * stride;     // alpha_l
          const T* dl = d + (l * C1 + C) * stride;
          for (int64_t s = 0; s < W; ++s) {
            dalpha[s] = dl[s];                            // sum_c x_c D_{l,c} + D_{l,C}
            sum_xd[s] += al[s] * dl[s];
          }
          for (int64_t c = 0; c < C; ++c) {
            const T* dc = d + (l * C1 + c) * stride;
            const T* xc = x + (b * C + c) * plane + row * W;
            const T* xlc = xs + (l * C1 + c) * stride;
            T* gx = grad_x + (b * C + c) * plane + row * W;
            for (int64_t s = 0; s < W; ++s) {
              dalpha[s] += xc[s] * dc[s];
              sum_xd[s] += xlc[s] * dc[s];
              gx[s] += al[s] * dc[s];
            }
          }
          const T lf = T(l);
          for (int64_t s = 0; s < W; ++s) {
            const T diff = qrow[s] - lf;
            const T sign = diff > T(0) ? T(1) : (diff < T(0) ? T(-1) : T(0));
            gq[s] -= (T(1) - std::abs(diff) >= T(0)) ? norm[s] * dalpha[s] * sign : T(0);
          }
        }
        for (int64_t c = 0; c < C; ++c) {
          T* gx = grad_x + (b * C + c) * plane + row * W;
          for (int64_t s = 0; s < W; ++s) gx[s] *= norm[s];
        }
        for (int64_t s = 0; s < W; ++s)
          gp[s] = norm[s] * m[s] * pol.scale(prow[s]) + sum_xd[s] * dnorm[s];
      }
    };
  });
}

}  // namespace

extern "C" {
#define DEFOCUS_SCATTER_ABI(T, S)                                                               \
  void gs_window_sums_##S(const T* sigma, T* line, T* moment, int64_t n, int64_t half,         \
                          int nthreads) {                                                      \
    window_sums(GaussPolicy<T>{half}, sigma, line, moment, n, nthreads);                       \
  }                                                                                            \
  void gs_forward_##S(const T* x, const T* sigma, const T* norm, T* y, int64_t B, int64_t C,   \
                      int64_t H, int64_t W, int64_t half, int nthreads) {                      \
    scatter_forward(GaussPolicy<T>{half}, x, sigma, norm, y, B, C, H, W, nthreads);            \
  }                                                                                            \
  void gs_backward_##S(const T* g, const T* x, const T* sigma, T* dx_raw, T* m1, int64_t B,    \
                       int64_t C, int64_t H, int64_t W, int64_t half, int nthreads) {          \
    scatter_backward(GaussPolicy<T>{half}, g, x, sigma, dx_raw, m1, B, C, H, W, nthreads);     \
  }                                                                                            \
  void cl_forward_##S(const T* x, const T* rho, const T* norm, const T* dist, T* y, int64_t B, \
                      int64_t C, int64_t H, int64_t W, int64_t half, int nthreads) {           \
    scatter_forward(ClampPolicy<T>{half, dist, nullptr, nullptr, 0}, x, rho, norm, y, B, C, H, \
                    W, nthreads);                                                              \
  }                                                                                            \
  void cl_backward_##S(const T* g, const T* x, const T* rho, const T* dist, T* dx_raw, T* m,   \
                       int64_t B, int64_t C, int64_t H, int64_t W, int64_t half, int nthreads) { \
    scatter_backward(ClampPolicy<T>{half, dist, nullptr, nullptr, 0}, g, x, rho, dx_raw, m, B, \
                     C, H, W, nthreads);                                                       \
  }                                                                                            \
  void cl_window_sums_##S(const T* rho, const T* dists, const T* counts, int64_t n_dists,     \
                          T* total, T* slope, int64_t n, int nthreads) {                       \
    window_sums(ClampPolicy<T>{0, nullptr, dists, counts, n_dists}, rho, total, slope, n,      \
                nthreads);                                                                     \
  }
DEFOCUS_SCATTER_ABI(float, f32)
DEFOCUS_SCATTER_ABI(double, f64)

#define DEFOCUS_FUSED_ABI(T, S)                                                                \
  void gs_render_##S(const T* x, const T* sigma, T* y, T* den, int64_t B, int64_t C, int64_t H, \
                     int64_t W, int64_t half, int nthreads) {                                   \
    fused_forward(GaussPolicy<T>{half}, x, sigma, y, den, B, C, H, W, nthreads);              \
  }                                                                                           \
  void gs_render_backward_##S(const T* g, const T* y, const T* den, const T* x,               \
                              const T* sigma, T* grad_x, T* grad_sigma, int64_t B, int64_t C, \
                              int64_t H, int64_t W, int64_t half, int nthreads) {             \
    fused_backward(GaussPolicy<T>{half}, g, y, den, x, sigma, grad_x, grad_sigma, B, C, H, W,   \
                   nthreads);                                                                 \
  }                                                                                           \
  void cl_render_##S(const T* x, const T* rho, const T* dist, const T* dists, const T* counts, \
                     int64_t n_dists, T* y, T* den, int64_t B, int64_t C, int64_t H, int64_t W, \
                     int64_t half, int nthreads) {                                              \
    fused_forward(ClampPolicy<T>{half, dist, dists, counts, n_dists}, x, rho, y, den, B, C, H, \
                  W, nthreads);                                                                \
  }                                                                                            \
  void cl_render_backward_##S(const T* g, const T* y, const T* den, const T* x, const T* rho,   \
                              const T* dist, const T* dists, const T* counts, int64_t n_dists,  \
                              T* grad_x, T* grad_rho, int64_t B, int64_t C, int64_t H,          \
                              int64_t W, int64_t half, int nthreads) {                          \
    fused_backward(ClampPolicy<T>{half, dist, dists, counts, n_dists}, g, y, den, x, rho,       \
                   grad_x, grad_rho, B, C, H, W, nthreads);                                     \
  }
DEFOCUS_FUSED_ABI(float, f32)
DEFOCUS_FUSED_ABI(double, f64)

#define DEFOCUS_LAYERED_ABI(T, S)                                                              \
  void gs_layered_##S(const T* x, const T* pos, const T* sigma, T* spread, T* out, int64_t B,  \
                      int64_t C, int64_t H, int64_t W, int64_t half, int64_t NL, int nthreads) { \
    layered_forward(GaussPolicy<T>{half}, x, pos, sigma, spread, out, B, C, H, W, NL, nthreads); \
  }                                                                                            \
  void gs_layered_backward_##S(const T* g, const T* out, const T* spread, const T* x,          \
                               const T* pos, const T* sigma, T* grad_x, T* grad_pos,           \
                               T* grad_sigma, int64_t B, int64_t C, int64_t H, int64_t W,      \
                               int64_t half, int64_t NL, int nthreads) {                       \
    layered_backward(GaussPolicy<T>{half}, g, out, spread, x, pos, sigma, grad_x, grad_pos,    \
                     grad_sigma, B, C, H, W, NL, nthreads);                                    \
  }                                                                                            \
  void cl_layered_##S(const T* x, const T* pos, const T* rho, const T* dist, const T* dists,   \
                      const T* counts, int64_t n_dists, T* spread, T* out, int64_t B,          \
                      int64_t C, int64_t H, int64_t W, int64_t half, int64_t NL, int nthreads) { \
    layered_forward(ClampPolicy<T>{half, dist, dists, counts, n_dists}, x, pos, rho, spread,   \
                    out, B, C, H, W, NL, nthreads);                                            \
  }                                                                                            \
  void cl_layered_backward_##S(const T* g, const T* out, const T* spread, const T* x,          \
                               const T* pos, const T* rho, const T* dist, const T* dists,      \
                               const T* counts, int64_t n_dists, T* grad_x, T* grad_pos,       \
                               T* grad_rho, int64_t B, int64_t C, int64_t H, int64_t W,        \
                               int64_t half, int64_t NL, int nthreads) {                       \
    layered_backward(ClampPolicy<T>{half, dist, dists, counts, n_dists}, g, out, spread, x,    \
                     pos, rho, grad_x, grad_pos, grad_rho, B, C, H, W, NL, nthreads);          \
  }
DEFOCUS_LAYERED_ABI(float, f32)
DEFOCUS_LAYERED_ABI(double, f64)
}
