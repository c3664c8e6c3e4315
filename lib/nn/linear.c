/* Linear layer and 1x1 convolution: both are one sgemm. */
#include "gazesplat/nn.h"
#include "nn_internal.h"

#include <cblas.h>
#include <string.h>

/* dst[rows,cols] = bias broadcast along rows (or zeros), the C operand of a
 * following sgemm with beta = 1. along_rows: bias[r] fills row r, else
 * bias[c] fills column c. */
static void fill_bias(float *dst, const float *bias, int rows, int cols,
                      int along_rows)
{
    size_t n = (size_t)rows * (size_t)cols;
    if (!bias) {
        memset(dst, 0, n * sizeof *dst);
        return;
    }
    for (int r = 0; r < rows; r++) {
        float *restrict row = dst + (size_t)r * (size_t)cols;
        if (!along_rows) {
            memcpy(row, bias, (size_t)cols * sizeof *row);
            continue;
        }
        /* blocks of 8, then the rest: GCC -O2 vectorises a loop only when
         * it needs no remainder of its own */
        float v = bias[r];
        int c = 0;
        for (; c + 8 <= cols; c += 8)
            for (int k = c; k < c + 8; k++)
                row[k] = v;
        for (; c < cols; c++)
            row[c] = v;
    }
}

/* db[r] += sum over columns of m[rows,cols] (double accumulator). */
static void add_row_sums(float *db, const float *m, int rows, int cols)
{
    for (int r = 0; r < rows; r++) {
        const float *row = m + (size_t)r * (size_t)cols;
        double s = 0.0;
        for (int c = 0; c < cols; c++)
            s += row[c];
        db[r] += (float)s;
    }
}

/* db[c] += sum over rows of m[rows,cols]. Columns go in chunks with double
 * accumulators so each row is read once per chunk; every column still sums
 * its rows in order. */
static void add_col_sums(float *db, const float *m, int rows, int cols)
{
    enum { CHUNK = 64 };
    double acc[CHUNK];
    for (int c0 = 0; c0 < cols; c0 += CHUNK) {
        int nc = cols - c0 < CHUNK ? cols - c0 : CHUNK;
        for (int c = 0; c < nc; c++)
            acc[c] = 0.0;
        for (int r = 0; r < rows; r++) {
            const float *row = m + (size_t)r * (size_t)cols + (size_t)c0;
            if (nc == CHUNK) /* a fixed trip count: GCC -O2 vectorises it */
                for (int c = 0; c < CHUNK; c++)
                    acc[c] += row[c];
            else
                for (int c = 0; c < nc; c++)
                    acc[c] += row[c];
        }
        for (int c = 0; c < nc; c++)
            db[c0 + c] += (float)acc[c];
    }
}

void gs_nn_blas_set_threads(int n)
{
    openblas_set_num_threads(n < 1 ? 1 : n);
}

int gs_nn_blas_threads(void)
{
    return openblas_get_num_threads();
}

static int linear_check(int B, int IC, int OC)
{
    int t;
    if (nn_sizes_ok3(B, IC, OC) != GS_OK)
        return GS_ERR_ARG;
    if (!nn_mul(B, IC, &t) || !nn_mul(B, OC, &t) || !nn_mul(OC, IC, &t))
        return GS_ERR_LIMIT;
    return GS_OK;
}

/* out[B,OC] = in[B,IC] . w[OC,IC]^T + b[OC] */
int gs_nn_linear_forward(float *out, const float *in, const float *w,
                         const float *b, int B, int IC, int OC)
{
    int rc = linear_check(B, IC, OC);
    if (rc)
        return rc;
    if (!out || !in || !w)
        return GS_ERR_ARG;
    fill_bias(out, b, B, OC, 0);
    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, B, OC, IC, 1.0f, in,
                IC, w, IC, 1.0f, out, OC);
    return GS_OK;
}

/* dinp[B,IC] += dout[B,OC] . w[OC,IC]; dw[OC,IC] += dout^T . in[B,IC];
 * db[OC] += column sums of dout */
int gs_nn_linear_backward(float *dinp, float *dw, float *db,
                          const float *dout, const float *in, const float *w,
                          int B, int IC, int OC)
{
    int rc = linear_check(B, IC, OC);
    if (rc)
        return rc;
    if (!dout || (dinp && !w) || (dw && !in))
        return GS_ERR_ARG;
    if (dinp)
        cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, B, IC, OC, 1.0f,
                    dout, OC, w, IC, 1.0f, dinp, IC);
    if (dw)
        cblas_sgemm(CblasRowMajor, CblasTrans, CblasNoTrans, OC, IC, B, 1.0f,
                    dout, OC, in, IC, 1.0f, dw, IC);
    if (db)
        add_col_sums(db, dout, B, OC);
    return GS_OK;
}

/* out[OC,HW] = w[OC,IC] . in[IC,HW] + b[OC] */
int gs_nn_conv1x1_forward(float *out, const float *in, const float *w,
                          const float *b, int IC, int OC, int HW)
{
    int rc = linear_check(HW, IC, OC);
    if (rc)
        return rc;
    if (!out || !in || !w)
        return GS_ERR_ARG;
    fill_bias(out, b, OC, HW, 1);
    cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, OC, HW, IC, 1.0f, w,
                IC, in, HW, 1.0f, out, HW);
    return GS_OK;
}

/* dinp[IC,HW] += w^T . dout[OC,HW]; dw[OC,IC] += dout . in^T;
 * db[OC] += row sums of dout */
int gs_nn_conv1x1_backward(float *dinp, float *dw, float *db,
                           const float *dout, const float *in, const float *w,
                           int IC, int OC, int HW)
{
    int rc = linear_check(HW, IC, OC);
    if (rc)
        return rc;
    if (!dout || (dinp && !w) || (dw && !in))
        return GS_ERR_ARG;
    if (dinp)
        cblas_sgemm(CblasRowMajor, CblasTrans, CblasNoTrans, IC, HW, OC, 1.0f,
                    w, IC, dout, HW, 1.0f, dinp, HW);
    if (dw)
        cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasTrans, OC, IC, HW, 1.0f,
                    dout, HW, in, HW, 1.0f, dw, IC);
    if (db)
        add_row_sums(db, dout, OC, HW);
    return GS_OK;
}
