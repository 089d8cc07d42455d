/* Fused elementwise passes of the chunked edge block (_kernels/edge_block.py).
 *
 * Each function does in one pass over a chunk of rows what takes the torch path
 * three to five passes and as many OpenMP fork/joins. Tensors are float32,
 * row-major and contiguous, `rows` x `width`; column sums are accumulated per
 * thread and added into the caller's totals at the end.
 *
 * Built by fused_kernels.py with -fopenmp: the library resolves libgomp.so.1 to
 * the one torch has already loaded, so both share one thread pool.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <omp.h>

/* Per-thread column sums: `count` rows of `width` floats per thread, zeroed. */
static float *thread_sums(int64_t count, int64_t width)
{
    return calloc((size_t)omp_get_max_threads() * count * width, sizeof(float));
}

static void add_thread_sums(const float *sums, int64_t count, int64_t width, float *const *totals)
{
    int threads = omp_get_max_threads();
    for (int t = 0; t < threads; ++t)
        for (int64_t k = 0; k < count; ++k) {
            if (!totals[k]) continue;
            const float *s = sums + ((int64_t)t * count + k) * width;
            for (int64_t c = 0; c < width; ++c) totals[k][c] += s[c];
        }
}

/* a = relu(a + bias), in place; NaN stays NaN, as in torch.relu. */
void bias_relu(int64_t rows, int64_t width, float *a, const float *bias)
{
#pragma omp parallel for schedule(static)
    for (int64_t r = 0; r < rows; ++r) {
        float *x = a + r * width;
#pragma omp simd
        for (int64_t c = 0; c < width; ++c) {
            const float v = x[c] + bias[c];
            x[c] = v < 0.f ? 0.f : v;
        }
    }
}

/* The first row of thread t's share of `rows` rows sorted by receiver, moved past the rows of
 * a receiver whose first row lies in the share before: no two threads add into one row. */
static int64_t share_start(int64_t rows, const int64_t *receivers, int t, int threads)
{
    int64_t r = rows * t / threads;
    while (r > 0 && r < rows && receivers[r] == receivers[r - 1]) ++r;
    return r;
}

/* a += bias (in place, when bias is not NULL); u = LayerNorm(a) * gamma + beta;
 * out = residual + u (out may be residual); aggregate[receivers[r]] += u[r], in row
 * order as index_add_ does, for receivers sorted ascending. mean and rstd (per row)
 * are written when not NULL. */
void layer_norm_residual(int64_t rows, int64_t width, float *a, const float *bias, const float *gamma,
                         const float *beta, float eps, const float *residual, float *out, float *aggregate,
                         const int64_t *receivers, float *mean, float *rstd)
{
#pragma omp parallel
    {
        const int t = omp_get_thread_num(), threads = omp_get_num_threads();
        const int64_t first = share_start(rows, receivers, t, threads);
        const int64_t end = share_start(rows, receivers, t + 1, threads);
        for (int64_t r = first; r < end; ++r) {
            float *x = a + r * width;
            const float *e = residual + r * width;
            float *o = out + r * width, *g = aggregate + receivers[r] * width;
            float sum = 0.f, squares = 0.f;
            if (bias) {
#pragma omp simd reduction(+ : sum)
                for (int64_t c = 0; c < width; ++c) {
                    x[c] += bias[c];
                    sum += x[c];
                }
            } else {
#pragma omp simd reduction(+ : sum)
                for (int64_t c = 0; c < width; ++c) sum += x[c];
            }
            const float m = sum / (float)width;
#pragma omp simd reduction(+ : squares)
            for (int64_t c = 0; c < width; ++c) squares += (x[c] - m) * (x[c] - m);
            const float rs = 1.f / sqrtf(squares / (float)width + eps);
#pragma omp simd
            for (int64_t c = 0; c < width; ++c) {
                const float u = (x[c] - m) * rs * gamma[c] + beta[c];
                o[c] = e[c] + u;
                g[c] += u;
            }
            if (mean) {
                mean[r] = m;
                rstd[r] = rs;
            }
        }
    }
}

/* Backward of layer_norm_residual from g = grad_aggregate[receivers[r]] + grad_out[r]
 * (either may be NULL; not both): writes grad_a, copies grad_out into grad_residual
 * (the residual's gradient, to which the caller adds the rest; untouched when grad_out
 * is NULL), and adds the column sums of g * xhat, of g and of grad_a into grad_gamma,
 * grad_beta and grad_bias (the last layer's bias; may be NULL). */
void layer_norm_backward(int64_t rows, int64_t width, const float *grad_aggregate, const int64_t *receivers,
                         const float *grad_out, const float *a, const float *mean, const float *rstd,
                         const float *gamma, float *grad_a, float *grad_residual, float *grad_gamma,
                         float *grad_beta, float *grad_bias)
{
    float *sums = thread_sums(3, width);
    if (!sums) abort();
#pragma omp parallel
    {
        float *sum_gamma = sums + (int64_t)omp_get_thread_num() * 3 * width;
        float *sum_beta = sum_gamma + width, *sum_bias = sum_beta + width;
#pragma omp for schedule(static)
        for (int64_t r = 0; r < rows; ++r) {
            const float *x = a + r * width;
            float *g = grad_a + r * width;
            const float m = mean[r], rs = rstd[r];
            if (grad_aggregate && grad_out) {
                const float *ga = grad_aggregate + receivers[r] * width, *go = grad_out + r * width;
                float *ge = grad_residual + r * width;
#pragma omp simd
                for (int64_t c = 0; c < width; ++c) {
                    g[c] = ga[c] + go[c];
                    ge[c] = go[c];
                }
            } else if (grad_aggregate) {
                const float *ga = grad_aggregate + receivers[r] * width;
#pragma omp simd
                for (int64_t c = 0; c < width; ++c) g[c] = ga[c];
            } else {
                const float *go = grad_out + r * width;
                float *ge = grad_residual + r * width;
#pragma omp simd
                for (int64_t c = 0; c < width; ++c) {
                    g[c] = go[c];
                    ge[c] = go[c];
                }
            }
            float gx_sum = 0.f, gx_xhat_sum = 0.f;
#pragma omp simd reduction(+ : gx_sum, gx_xhat_sum)
            for (int64_t c = 0; c < width; ++c) {
                const float xhat = (x[c] - m) * rs, gx = g[c] * gamma[c];
                sum_gamma[c] += g[c] * xhat;
                sum_beta[c] += g[c];
                gx_sum += gx;
                gx_xhat_sum += gx * xhat;
            }
            const float c1 = gx_sum / (float)width, c2 = gx_xhat_sum / (float)width;
#pragma omp simd
            for (int64_t c = 0; c < width; ++c) {
                const float xhat = (x[c] - m) * rs;
                const float d = rs * (g[c] * gamma[c] - c1 - xhat * c2);
                g[c] = d;
                sum_bias[c] += d;
            }
        }
    }
    float *const totals[3] = {grad_gamma, grad_beta, grad_bias};
    add_thread_sums(sums, 3, width, totals);
    free(sums);
}

/* grad = 0 where z <= 0, in place (as torch's threshold_backward); adds its column sums into
 * grad_bias when not NULL. */
void relu_backward(int64_t rows, int64_t width, float *grad, const float *z, float *grad_bias)
{
    float *sums = grad_bias ? thread_sums(1, width) : NULL;
    if (grad_bias && !sums) abort();
#pragma omp parallel
    {
        float *sum_bias = sums ? sums + (int64_t)omp_get_thread_num() * width : NULL;
#pragma omp for schedule(static)
        for (int64_t r = 0; r < rows; ++r) {
            float *g = grad + r * width;
            const float *y = z + r * width;
#pragma omp simd
            for (int64_t c = 0; c < width; ++c) g[c] = y[c] <= 0.f ? 0.f : g[c];
            if (sum_bias) {
#pragma omp simd
                for (int64_t c = 0; c < width; ++c) sum_bias[c] += g[c];
            }
        }
    }
    if (sums) {
        float *const totals[1] = {grad_bias};
        add_thread_sums(sums, 1, width, totals);
        free(sums);
    }
}
