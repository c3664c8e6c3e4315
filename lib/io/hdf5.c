/* ETH-XGaze-style HDF5 files (gazesplat/xgaze_h5.h) through libhdf5's C
 * API. HDF5's own error printing is turned off for each call; failures
 * come back as gs_error messages naming the dataset. */
#include <hdf5.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "gazesplat/xgaze_h5.h"

struct gs_h5_reader {
    hid_t file, patch, gaze, head;
    gs_h5_info info;
};

struct gs_h5_writer {
    hid_t file, patch, gaze, head;
    size_t rows, written;
    int size;
    int failed;
};

static void quiet(void)
{
    H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
}

/* Rank and dims of a dataset; -1 on failure. */
static int dims_of(hid_t ds, hsize_t *dims, int max)
{
    hid_t sp = H5Dget_space(ds);
    if (sp < 0)
        return -1;
    int rank = H5Sget_simple_extent_ndims(sp);
    if (rank >= 0 && rank <= max)
        H5Sget_simple_extent_dims(sp, dims, NULL);
    else if (rank > max)
        rank = max + 1;
    H5Sclose(sp);
    return rank;
}

/* An N x 2 float dataset, optional: *out < 0 when absent. */
static int open_labels(hid_t file, const char *name, size_t rows, hid_t *out,
                       const char *path, gs_error *err)
{
    *out = -1;
    if (H5Lexists(file, name, H5P_DEFAULT) <= 0)
        return GS_OK;
    hid_t ds = H5Dopen2(file, name, H5P_DEFAULT);
    if (ds < 0)
        return gs_error_set(err, GS_ERR_FORMAT, "%s: %s is not a dataset", path, name);
    hsize_t d[4] = {0, 0, 0, 0};
    int rank = dims_of(ds, d, 3);
    hid_t t = H5Dget_type(ds);
    H5T_class_t cls = t >= 0 ? H5Tget_class(t) : H5T_NO_CLASS;
    if (t >= 0)
        H5Tclose(t);
    if (rank != 2 || d[0] != rows || d[1] != 2 || cls != H5T_FLOAT) {
        H5Dclose(ds);
        if (rank != 2 || d[1] != 2 || d[0] != rows)
            return gs_error_set(err, GS_ERR_FORMAT,
                                "%s: %s has shape %s; want %zu x 2 (face_patch has %zu rows)",
                                path, name,
                                rank == 1   ? "of rank 1"
                                : rank == 2 ? "N x M"
                                            : "of another rank",
                                rows, rows);
        return gs_error_set(err, GS_ERR_FORMAT, "%s: %s is not of a float type", path, name);
    }
    *out = ds;
    return GS_OK;
}

int gs_h5_open(const char *path, gs_h5_reader **out, gs_h5_info *info, gs_error *err)
{
    *out = NULL;
    quiet();
    if (H5Fis_hdf5(path) <= 0)
        return gs_error_set(err, GS_ERR_IO, "%s: cannot open as HDF5", path);
    gs_h5_reader *r = calloc(1, sizeof *r);
    if (!r)
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    r->patch = r->gaze = r->head = -1;
    r->file = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
    if (r->file < 0) {
        free(r);
        return gs_error_set(err, GS_ERR_IO, "%s: cannot open as HDF5", path);
    }
    int rc = GS_OK;
    if (H5Lexists(r->file, "face_patch", H5P_DEFAULT) <= 0 ||
        (r->patch = H5Dopen2(r->file, "face_patch", H5P_DEFAULT)) < 0)
        rc = gs_error_set(err, GS_ERR_FORMAT, "%s: no dataset face_patch", path);
    hsize_t d[5] = {0, 0, 0, 0, 0};
    if (rc == GS_OK) {
        int rank = dims_of(r->patch, d, 4);
        hid_t t = H5Dget_type(r->patch);
        int ok_type = t >= 0 && H5Tget_class(t) == H5T_INTEGER && H5Tget_size(t) == 1 &&
                      H5Tget_sign(t) == H5T_SGN_NONE;
        if (t >= 0)
            H5Tclose(t);
        if (rank != 4 || d[3] != 3)
            rc = gs_error_set(err, GS_ERR_FORMAT,
                              "%s: face_patch has rank %d%s; want N x H x W x 3", path, rank,
                              rank == 4 ? " but not 3 channels" : "");
        else if (!ok_type)
            rc = gs_error_set(err, GS_ERR_FORMAT, "%s: face_patch is not uint8", path);
        else if (d[1] < 1 || d[2] < 1 || d[1] > GS_H5_MAX_SIDE || d[2] > GS_H5_MAX_SIDE ||
                 d[0] > GS_H5_MAX_ROWS)
            rc = gs_error_set(err, GS_ERR_LIMIT, "%s: face_patch is %llu x %llu x %llu x 3 (limits: "
                              "sides <= %d, rows <= 2^31)", path, (unsigned long long)d[0],
                              (unsigned long long)d[1], (unsigned long long)d[2], GS_H5_MAX_SIDE);
    }
    if (rc == GS_OK) {
        r->info.rows = (size_t)d[0];
        r->info.height = (int)d[1];
        r->info.width = (int)d[2];
        rc = open_labels(r->file, "face_gaze", r->info.rows, &r->gaze, path, err);
    }
    if (rc == GS_OK)
        rc = open_labels(r->file, "face_head_pose", r->info.rows, &r->head, path, err);
    if (rc != GS_OK) {
        gs_h5_close(r);
        return rc;
    }
    r->info.has_gaze = r->gaze >= 0;
    r->info.has_head = r->head >= 0;
    if (info)
        *info = r->info;
    *out = r;
    return GS_OK;
}

/* Reads count rows starting at row0 of a dataset whose rows are `row`
 * elements of mem_type. */
static int read_rows(hid_t ds, int rank, size_t row0, const hsize_t *row_dims, hid_t mem_type,
                     void *buf)
{
    hsize_t start[4] = {row0, 0, 0, 0}, count[4] = {1, 0, 0, 0};
    for (int i = 1; i < rank; i++)
        count[i] = row_dims[i];
    hid_t fs = H5Dget_space(ds);
    if (fs < 0)
        return -1;
    hid_t ms = H5Screate_simple(rank, count, NULL);
    int bad = ms < 0 || H5Sselect_hyperslab(fs, H5S_SELECT_SET, start, NULL, count, NULL) < 0 ||
              H5Dread(ds, mem_type, ms, fs, H5P_DEFAULT, buf) < 0;
    if (ms >= 0)
        H5Sclose(ms);
    H5Sclose(fs);
    return bad ? -1 : 0;
}

static int read_label(gs_h5_reader *r, hid_t ds, const char *name, size_t row, float v[2],
                      gs_error *err)
{
    float tmp[2] = {NAN, NAN};
    if (ds >= 0) {
        hsize_t d[2] = {1, 2};
        if (read_rows(ds, 2, row, d, H5T_NATIVE_FLOAT, tmp))
            return gs_error_set(err, GS_ERR_IO, "%s row %zu: cannot read", name, row);
        if (!isfinite(tmp[0]) || !isfinite(tmp[1]))
            return gs_error_set(err, GS_ERR_NONFINITE, "%s row %zu: %g, %g is not finite", name,
                                row, (double)tmp[0], (double)tmp[1]);
    }
    (void)r;
    if (v) {
        v[0] = tmp[0];
        v[1] = tmp[1];
    }
    return GS_OK;
}

int gs_h5_read_row(gs_h5_reader *r, size_t row, uint8_t *patch, float gaze[2], float head[2],
                   gs_error *err)
{
    quiet();
    if (row >= r->info.rows)
        return gs_error_set(err, GS_ERR_ARG, "row %zu of %zu", row, r->info.rows);
    hsize_t d[4] = {1, (hsize_t)r->info.height, (hsize_t)r->info.width, 3};
    if (patch && read_rows(r->patch, 4, row, d, H5T_NATIVE_UCHAR, patch))
        return gs_error_set(err, GS_ERR_IO, "face_patch row %zu: cannot read", row);
    int rc = read_label(r, r->gaze, "face_gaze", row, gaze, err);
    return rc ? rc : read_label(r, r->head, "face_head_pose", row, head, err);
}

void gs_h5_close(gs_h5_reader *r)
{
    if (!r)
        return;
    quiet();
    if (r->patch >= 0)
        H5Dclose(r->patch);
    if (r->gaze >= 0)
        H5Dclose(r->gaze);
    if (r->head >= 0)
        H5Dclose(r->head);
    if (r->file >= 0)
        H5Fclose(r->file);
    free(r);
}

static hid_t make_dataset(hid_t file, const char *name, hid_t type, int rank, const hsize_t *dims)
{
    hid_t sp = H5Screate_simple(rank, dims, NULL);
    hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
    hid_t ds = -1;
    /* No timestamps (same rows, same bytes); space allocated up front and
     * filled with zeros, so unwritten rows are zeros, never stale bytes. */
    if (sp >= 0 && dcpl >= 0 && H5Pset_obj_track_times(dcpl, 0) >= 0 &&
        H5Pset_alloc_time(dcpl, H5D_ALLOC_TIME_EARLY) >= 0 &&
        H5Pset_fill_time(dcpl, H5D_FILL_TIME_ALLOC) >= 0)
        ds = H5Dcreate2(file, name, type, sp, H5P_DEFAULT, dcpl, H5P_DEFAULT);
    if (dcpl >= 0)
        H5Pclose(dcpl);
    if (sp >= 0)
        H5Sclose(sp);
    return ds;
}

int gs_h5_create(const char *path, size_t rows, int size, gs_h5_writer **out, gs_error *err)
{
    *out = NULL;
    quiet();
    if (size < 1 || size > GS_H5_MAX_SIDE || rows > GS_H5_MAX_ROWS)
        return gs_error_set(err, GS_ERR_ARG, "%s: %zu rows of %d px: out of range", path, rows,
                            size);
    gs_h5_writer *w = calloc(1, sizeof *w);
    if (!w)
        return gs_error_set(err, GS_ERR_NOMEM, "out of memory");
    w->patch = w->gaze = w->head = -1;
    w->rows = rows;
    w->size = size;
    hid_t fcpl = H5Pcreate(H5P_FILE_CREATE);
    if (fcpl >= 0)
        H5Pset_obj_track_times(fcpl, 0);
    w->file = H5Fcreate(path, H5F_ACC_TRUNC, fcpl >= 0 ? fcpl : H5P_DEFAULT, H5P_DEFAULT);
    if (fcpl >= 0)
        H5Pclose(fcpl);
    if (w->file < 0) {
        free(w);
        return gs_error_set(err, GS_ERR_IO, "%s: cannot create", path);
    }
    hsize_t dp[4] = {rows, (hsize_t)size, (hsize_t)size, 3}, dl[2] = {rows, 2};
    w->patch = make_dataset(w->file, "face_patch", H5T_STD_U8LE, 4, dp);
    w->gaze = make_dataset(w->file, "face_gaze", H5T_IEEE_F32LE, 2, dl);
    w->head = make_dataset(w->file, "face_head_pose", H5T_IEEE_F32LE, 2, dl);
    if (w->patch < 0 || w->gaze < 0 || w->head < 0) {
        gs_h5_abort(w);
        return gs_error_set(err, GS_ERR_IO, "%s: cannot create the datasets (disk full?)", path);
    }
    *out = w;
    return GS_OK;
}

static int write_part(hid_t ds, int rank, size_t row0, size_t count, const hsize_t *row_dims,
                      hid_t mem_type, const void *buf)
{
    hsize_t start[4] = {row0, 0, 0, 0}, cnt[4] = {count, 0, 0, 0};
    for (int i = 1; i < rank; i++)
        cnt[i] = row_dims[i];
    hid_t fs = H5Dget_space(ds);
    if (fs < 0)
        return -1;
    hid_t ms = H5Screate_simple(rank, cnt, NULL);
    int bad = ms < 0 || H5Sselect_hyperslab(fs, H5S_SELECT_SET, start, NULL, cnt, NULL) < 0 ||
              H5Dwrite(ds, mem_type, ms, fs, H5P_DEFAULT, buf) < 0;
    if (ms >= 0)
        H5Sclose(ms);
    H5Sclose(fs);
    return bad ? -1 : 0;
}

int gs_h5_write_rows(gs_h5_writer *w, size_t row0, size_t count, const uint8_t *patches,
                     const float *gaze, const float *head, gs_error *err)
{
    quiet();
    if (row0 > w->rows || count > w->rows - row0)
        return gs_error_set(err, GS_ERR_ARG, "rows %zu + %zu of %zu", row0, count, w->rows);
    if (count == 0)
        return GS_OK;
    hsize_t dp[4] = {0, (hsize_t)w->size, (hsize_t)w->size, 3}, dl[2] = {0, 2};
    if (write_part(w->patch, 4, row0, count, dp, H5T_NATIVE_UCHAR, patches) ||
        write_part(w->gaze, 2, row0, count, dl, H5T_NATIVE_FLOAT, gaze) ||
        write_part(w->head, 2, row0, count, dl, H5T_NATIVE_FLOAT, head)) {
        w->failed = 1;
        return gs_error_set(err, GS_ERR_IO, "cannot write rows %zu..%zu (disk full?)", row0,
                            row0 + count - 1);
    }
    w->written += count;
    return GS_OK;
}

int gs_h5_finish(gs_h5_writer *w, gs_error *err)
{
    quiet();
    int rc = GS_OK;
    if (w->failed || w->written != w->rows)
        rc = gs_error_set(err, GS_ERR_STATE, "%zu of %zu rows written", w->written, w->rows);
    int bad = H5Dclose(w->patch) < 0;
    bad |= H5Dclose(w->gaze) < 0;
    bad |= H5Dclose(w->head) < 0;
    w->patch = w->gaze = w->head = -1;
    bad |= H5Fflush(w->file, H5F_SCOPE_GLOBAL) < 0;
    bad |= H5Fclose(w->file) < 0;
    free(w);
    if (bad && rc == GS_OK)
        rc = gs_error_set(err, GS_ERR_IO, "cannot flush the file (disk full?)");
    return rc;
}

void gs_h5_abort(gs_h5_writer *w)
{
    if (!w)
        return;
    quiet();
    if (w->patch >= 0)
        H5Dclose(w->patch);
    if (w->gaze >= 0)
        H5Dclose(w->gaze);
    if (w->head >= 0)
        H5Dclose(w->head);
    if (w->file >= 0)
        H5Fclose(w->file);
    free(w);
}
