/* Datasets on disk (PNG images and masks, labels.jsonl, README.md) and the
 * contact sheet. */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "gazesplat/image_io.h"
#include "synth_internal.h"

static const char *const split_names[3] = {"train", "val", "test"};
static const char *const rig_names[3] = {"single", "ethx", "normalized"};

static const char readme_fields[] =
    "## Files\n"
    "\n"
    "- `images/NNNNNNNN.png`: 8-bit sRGB RGB image (N = generator index).\n"
    "- `masks/NNNNNNNN.png`: masks as one RGB PNG: R = 255 on the head\n"
    "  (skin, hair, eyes, neck), G = 255 on the face (face skin from forehead\n"
    "  to chin incl. lids and lips; eyeballs, hair, ears and neck excluded),\n"
    "  B = 255 on the visible eyeball of the subject's LEFT eye and 128 on the\n"
    "  subject's RIGHT eye. Face and eye masks are disjoint, inside the head.\n"
    "- `labels.jsonl`: one JSON object per image, in index order.\n"
    "\n"
    "## Conventions\n"
    "\n"
    "- Camera frame: OpenCV (x right, y down, z forward), millimetres.\n"
    "- Head frame: x toward image right (the subject's left), y down, z into\n"
    "  the head; origin at the face centre of the identity's neutral face =\n"
    "  midpoint of the eye-corner centre (iBUG 36, 39, 42, 45) and the\n"
    "  nose-wing centre (31, 35). X_cam = head_R X_head + head_t.\n"
    "- Pixels: pixel (i, j) covers [i, i+1) x [j, j+1), its centre is\n"
    "  (i + 0.5, j + 0.5) (OpenCV puts centres at integers: subtract 0.5).\n"
    "- Gaze (ETH-XGaze convention): unit vector g from the face centre toward\n"
    "  the target; pitch = asin(-g_y), yaw = atan2(-g_x, -g_z); pitch > 0 looks\n"
    "  up, yaw > 0 looks toward image-left; g = (-cos p sin y, -sin p,\n"
    "  -cos p cos y). Both eyes look along g (parallel axes, no kappa).\n"
    "- Head angles: those of the head's z-axis z = head_R e_z: pitch =\n"
    "  asin(z_y), yaw = atan2(z_x, z_z); roll about that axis.\n"
    "- Normalization (Zhang, Sugano, Bulling, ETRA 2018) with d_n = 680 mm and\n"
    "  f_n = 1600 px at 512 px (scaled to this image size): forward = c/|c|,\n"
    "  down = norm(forward x head x-axis), right = norm(down x forward),\n"
    "  R = [right; down; forward], W = K_n S R K^-1; gaze and head rotation\n"
    "  are rotated by R only.\n"
    "- Eyes are named from the subject: index 0 = right eye (iBUG 36-41,\n"
    "  image left in a frontal view), index 1 = left eye (42-47).\n"
    "- Landmarks: the 68 iBUG points as fixed 3D points of the model\n"
    "  (eye points on the lid margins, jaw points on a fixed jaw contour, not\n"
    "  the view-dependent silhouette). Points behind the camera are null.\n"
    "\n"
    "## Fields of labels.jsonl\n"
    "\n"
    "| field | meaning |\n"
    "|---|---|\n"
    "| image, mask | file names relative to this directory |\n"
    "| index | generator index |\n"
    "| width, height | image size, px |\n"
    "| identity_seed, split | identity seed and the split its range belongs to |\n"
    "| K | intrinsics, 3x3 row-major |\n"
    "| cam_R, cam_t_mm | world-to-camera rotation (row-major) and translation |\n"
    "| head_R, head_t_mm | head-to-camera rotation and translation (head_t = face centre) |\n"
    "| head_rvec | head_R as a Rodrigues vector |\n"
    "| head_pitch_rad, head_yaw_rad, head_roll_rad | head angles in the camera |\n"
    "| gaze_head, gaze_head_pitch_rad, gaze_head_yaw_rad | gaze in the head frame |\n"
    "| gaze_cam, gaze_cam_pitch_rad, gaze_cam_yaw_rad | gaze in the camera frame |\n"
    "| gaze_norm_pitch_rad, gaze_norm_yaw_rad | gaze in the normalized frame |\n"
    "| head_norm_pitch_rad, head_norm_yaw_rad | head angles in the normalized frame |\n"
    "| norm_R, norm_W, norm_K | normalization rotation, pixel warp, normalized intrinsics |\n"
    "| norm_distance_mm, face_distance_mm | d_n and the face centre's distance |\n"
    "| face_centre_mm, face_centre_px | face centre, camera frame and pixels |\n"
    "| eye_centre_mm, eye_centre_px | eyeball centres [right, left] |\n"
    "| pupil_centre_mm, pupil_centre_px | pupil centres [right, left] |\n"
    "| pupil_radius_mm, iris_radius_mm, eyeball_radius_mm | eye sizes |\n"
    "| landmarks_px | 68 x 2 pixel positions |\n"
    "| landmarks_mm, landmarks_head_mm | 68 x 3, camera and head frames |\n"
    "| identity | the identity parameters by name, each in [-1, 1] |\n"
    "| expression | mouth_open, smile, brow_raise, squint, blink (0..1 or -1..1), pupil |\n";

/* Written after the fields only when kappa is on (without it the README
 * keeps its bytes). */
static const char readme_kappa[] =
    "\n## Angle kappa\n"
    "\n"
    "`gaze` means the visual axis (line of sight) in every frame; each eyeball\n"
    "renders along its optical axis, the visual axis turned temporally by\n"
    "kappa_h and down by kappa_v (the identity's own, drawn from its seed).\n"
    "\n"
    "| field | meaning |\n"
    "|---|---|\n"
    "| gaze_axis | \"visual\": which axis the gaze_* fields give |\n"
    "| kappa_h_rad, kappa_v_rad | the identity's kappa: visual axis nasal / up of the optical axis |\n"
    "| gaze_optical_head, gaze_optical_cam | optical axes [right, left], unit, head and camera frames |\n"
    "| gaze_optical_{head,cam,norm}_{pitch,yaw}_rad | their angles [right, left] |\n";

static int make_dir(const char *path, gs_error *err)
{
    if (mkdir(path, 0777) == 0)
        return GS_OK;
    struct stat st;
    if (errno == EEXIST && stat(path, &st) == 0 && S_ISDIR(st.st_mode))
        return GS_OK;
    return gs_error_set(err, GS_ERR_IO, "dataset: cannot create directory %s: %s",
                        path, strerror(errno));
}

/* The shortest of %.15g and %.17g that reads back as v (the config
 * reader must find the same bits). */
static void exact(char buf[32], double v)
{
    snprintf(buf, 32, "%.15g", v);
    if (strtod(buf, NULL) != v)
        snprintf(buf, 32, "%.17g", v);
}

static int write_readme(const char *dir, const gs_synth_gen_config *c,
                        const gs_synth_dataset_opts *o, gs_error *err)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/README.md", dir);
    FILE *f = fopen(path, "w");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "dataset: cannot write %s", path);
    fprintf(f, "# Synthetic gaze dataset (gazesplat synth)\n\n"
               "%llu images, generator indices %llu..%llu; split %s (identity "
               "seeds %llu + k, k < %llu), scene seed %llu, %dx%d px, rig %s, "
               "%s.\n\n",
            (unsigned long long)o->count, (unsigned long long)o->first,
            (unsigned long long)(o->first + o->count - (o->count ? 1 : 0)),
            split_names[c->split], (unsigned long long)gs_synth_split_seed(c->split, 0),
            (unsigned long long)c->identities, (unsigned long long)c->seed, c->size,
            c->size, rig_names[c->rig],
            c->supersample == 2 ? "2x2 supersampled" : "one sample per pixel");
    if (c->rig == GS_SYNTH_RIG_ETHX)
        fprintf(f, "Rig ethx: image N is camera N %% 18 of frame N / 18; the 18 "
                   "views of a frame show the same scene. Cameras: 3 rows (pitch "
                   "+20, 0, -20 deg) x 6 columns (yaw 62.5 .. -62.5 deg, image-left "
                   "first) on a sphere around the head's nominal position.\n\n");
    if (c->kappa.enabled) {
        char k[4][32];
        exact(k[0], c->kappa.h_mean_deg);
        exact(k[1], c->kappa.h_sd_deg);
        exact(k[2], c->kappa.v_mean_deg);
        exact(k[3], c->kappa.v_sd_deg);
        fprintf(f, "Angle kappa per identity: horizontal %s +- %s deg, "
                   "vertical %s +- %s deg (normal, truncated at 3 sd).\n\n",
                k[0], k[1], k[2], k[3]);
    }
    fputs(readme_fields, f);
    if (c->kappa.enabled)
        fputs(readme_kappa, f);
    int bad = ferror(f);
    bad |= fclose(f) != 0;
    return bad ? gs_error_set(err, GS_ERR_IO, "dataset: cannot write %s", path)
               : GS_OK;
}

/* Packs the four masks into one RGB image (see readme_fields). */
static void pack_masks(const gs_synth_sample *s, uint8_t *rgb)
{
    size_t plane = (size_t)s->width * (size_t)s->height;
    for (size_t i = 0; i < plane; i++) {
        rgb[3 * i] = s->mask[i + plane * GS_SYNTH_MASK_HEAD];
        rgb[3 * i + 1] = s->mask[i + plane * GS_SYNTH_MASK_FACE];
        rgb[3 * i + 2] = s->mask[i + plane * GS_SYNTH_MASK_LEFT_EYE]
                             ? 255
                             : (s->mask[i + plane * GS_SYNTH_MASK_RIGHT_EYE] ? 128 : 0);
    }
}

static int write_png(const char *path, int w, int h, size_t stride,
                     const uint8_t *rgb, gs_error *err)
{
    gs_io_image img = {w, h, stride, (unsigned char *)rgb};
    return gs_io_image_write(path, &img, GS_IO_PNG, 0, err);
}

/* One sample: image, mask and its labels line. */
static int write_one(const char *dir, const gs_synth_gen_config *c,
                     const gs_synth_dataset_opts *o, uint64_t index,
                     gs_pool *pool, gs_synth_sample *s, uint8_t *mask_rgb,
                     char **line, size_t *line_cap, FILE *labels, gs_error *err)
{
    int rc = gs_synth_gen_sample(c, index, pool, s, err);
    if (rc != GS_OK)
        return rc;
    char name[64], mname[64], path[4096];
    snprintf(name, sizeof name, "images/%08llu.png", (unsigned long long)index);
    snprintf(mname, sizeof mname, "masks/%08llu.png", (unsigned long long)index);
    snprintf(path, sizeof path, "%s/%s", dir, name);
    rc = write_png(path, s->width, s->height, s->stride, s->rgb, err);
    if (rc == GS_OK && o->masks) {
        pack_masks(s, mask_rgb);
        snprintf(path, sizeof path, "%s/%s", dir, mname);
        rc = write_png(path, s->width, s->height, 3 * (size_t)s->width, mask_rgb, err);
    }
    if (rc != GS_OK)
        return rc;
    for (;;) {
        int n = gs_synth_labels_json(&s->labels, name, *line, *line_cap);
        if (n < 0)
            return gs_error_set(err, n, "dataset: labels too long");
        if ((size_t)n < *line_cap)
            break;
        char *grown = realloc(*line, (size_t)n + 1);
        if (!grown)
            return gs_error_set(err, GS_ERR_NOMEM, "dataset: out of memory");
        *line = grown;
        *line_cap = (size_t)n + 1;
    }
    /* Splice the index and mask name in after the image name. */
    size_t head = strlen("{\"image\":\"") + strlen(name) + 1;
    fprintf(labels, "%.*s,\"index\":%llu", (int)head, *line,
            (unsigned long long)index);
    if (o->masks)
        fprintf(labels, ",\"mask\":\"%s\"", mname);
    fprintf(labels, "%s\n", *line + head);
    return ferror(labels) ? gs_error_set(err, GS_ERR_IO, "dataset: write failed")
                          : GS_OK;
}

int gs_synth_dataset_write(const char *dir, const gs_synth_gen_config *c,
                           const gs_synth_dataset_opts *o, gs_pool *pool,
                           gs_error *err)
{
    if (!dir || !*dir || strlen(dir) > 3900)
        return gs_error_set(err, GS_ERR_ARG, "dataset: bad directory name");
    gs_synth_scene sc;
    gs_synth_camera cam;
    int rc = gs_synth_gen_scene(c, 0, &sc, &cam, err); /* checks the config */
    if (rc != GS_OK)
        return rc;
    char path[4096];
    rc = make_dir(dir, err);
    snprintf(path, sizeof path, "%s/images", dir);
    if (rc == GS_OK)
        rc = make_dir(path, err);
    snprintf(path, sizeof path, "%s/masks", dir);
    if (rc == GS_OK && o->masks)
        rc = make_dir(path, err);
    if (rc == GS_OK)
        rc = write_readme(dir, c, o, err);
    if (rc != GS_OK)
        return rc;
    snprintf(path, sizeof path, "%s/labels.jsonl", dir);
    FILE *labels = fopen(path, "w");
    if (!labels)
        return gs_error_set(err, GS_ERR_IO, "dataset: cannot write %s", path);
    gs_synth_sample s;
    size_t line_cap = 1 << 16;
    char *line = malloc(line_cap);
    uint8_t *mask_rgb = malloc(3 * (size_t)c->size * (size_t)c->size);
    rc = gs_synth_sample_alloc(&s, c->size, c->size, err);
    if (rc == GS_OK && (!line || !mask_rgb))
        rc = gs_error_set(err, GS_ERR_NOMEM, "dataset: out of memory");
    for (uint64_t i = 0; rc == GS_OK && i < o->count; i++) {
        rc = write_one(dir, c, o, o->first + i, pool, &s, mask_rgb, &line,
                       &line_cap, labels, err);
        if (rc == GS_OK && o->progress)
            o->progress(o->progress_ctx, i + 1, o->count);
    }
    if (fclose(labels) != 0 && rc == GS_OK)
        rc = gs_error_set(err, GS_ERR_IO, "dataset: cannot write labels.jsonl");
    gs_synth_sample_free(&s);
    free(line);
    free(mask_rgb);
    return rc;
}

/* ---- contact sheet ---- */

int gs_synth_contact_sheet(gs_synth_split split, int rows, int tile,
                           gs_pool *pool, uint8_t **rgb, int *width,
                           int *height, gs_error *err)
{
    static const double pitch_deg[3] = {25, 0, -25}, yaw_deg[3] = {35, 0, -35};
    const double deg = 3.14159265358979323846 / 180.0;
    *rgb = NULL;
    if (rows < 1 || rows > 64 || tile < 16 || tile > 1024)
        return gs_error_set(err, GS_ERR_ARG,
                            "sheet: rows 1..64 and tile 16..1024 (got %d, %d)",
                            rows, tile);
    int w = 9 * tile, h = rows * tile;
    uint8_t *out = malloc(3 * (size_t)w * (size_t)h);
    gs_synth_sample s;
    int rc = gs_synth_sample_alloc(&s, tile, tile, err);
    if (rc == GS_OK && !out)
        rc = gs_error_set(err, GS_ERR_NOMEM, "sheet: out of memory");
    gs_synth_ranges rg;
    gs_synth_ranges_default(&rg);
    rg.head_yaw = 15 * deg;
    rg.head_pitch = 10 * deg;
    rg.head_roll = 5 * deg;
    rg.expression_prob = 0.0f;
    rg.blink_prob = 0.0f;
    gs_synth_render_opts opts = {.supersample = 2};
    for (int r = 0; rc == GS_OK && r < rows; r++) {
        gs_synth_scene sc;
        gs_synth_scene_random(gs_synth_split_seed(split, (uint64_t)r), 101u + (uint64_t)r,
                              &rg, &sc);
        sc.expr.pupil = 0.0f;
        gs_synth_camera base, cam;
        gs_synth_camera_single(tile, 600.0, 260.0, &base);
        rc = gs_synth_camera_normalized(&sc, &base, tile, 0.0, 0.0, &cam, err);
        for (int k = 0; rc == GS_OK && k < 9; k++) {
            sc.gaze_pitch = pitch_deg[k / 3] * deg;
            sc.gaze_yaw = yaw_deg[k % 3] * deg;
            rc = gs_synth_render(&sc, &cam, &opts, pool, &s, err);
            for (int y = 0; rc == GS_OK && y < tile; y++)
                memcpy(out + 3 * ((size_t)(r * tile + y) * (size_t)w + (size_t)(k * tile)),
                       s.rgb + (size_t)y * s.stride, 3 * (size_t)tile);
        }
    }
    gs_synth_sample_free(&s);
    if (rc != GS_OK) {
        free(out);
        return rc;
    }
    *rgb = out;
    *width = w;
    *height = h;
    return GS_OK;
}

/* Reads the generator configuration back from the first lines of a
 * dataset's README.md (the ranges are the defaults: the only ones the
 * writer's callers use). */
int gs_synth_dataset_config_read(const char *dir, gs_synth_gen_config *c,
                                 uint64_t *first, uint64_t *count, gs_error *err)
{
    char path[4096], text[2048];
    if (!dir || strlen(dir) > 3900)
        return gs_error_set(err, GS_ERR_ARG, "dataset: bad directory name");
    snprintf(path, sizeof path, "%s/README.md", dir);
    FILE *f = fopen(path, "r");
    if (!f)
        return gs_error_set(err, GS_ERR_IO, "dataset: cannot read %s: %s", path,
                            strerror(errno));
    size_t n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[n] = '\0';
    gs_synth_gen_config_default(c);
    unsigned long long cnt, f0, last, s0, ids, seed;
    int w, h;
    char split[16], rig[16], ss[32];
    const char *head = "# Synthetic gaze dataset (gazesplat synth)\n\n";
    if (strncmp(text, head, strlen(head)) != 0 ||
        sscanf(text + strlen(head),
               "%llu images, generator indices %llu..%llu; split %15s (identity "
               "seeds %llu + k, k < %llu), scene seed %llu, %dx%d px, rig %15[a-z], %31[^.]",
               &cnt, &f0, &last, split, &s0, &ids, &seed, &w, &h, rig, ss) != 11)
        return gs_error_set(err, GS_ERR_FORMAT, "dataset: %s is not a gazesplat "
                            "synth README (its first lines name the generator)", path);
    int k = 0;
    while (k < 3 && strcmp(split, split_names[k]) != 0)
        k++;
    int r = 0;
    while (r < 3 && strcmp(rig, rig_names[r]) != 0)
        r++;
    if (k == 3 || r == 3 || w != h || ids < 1)
        return gs_error_set(err, GS_ERR_FORMAT, "dataset: %s: unknown split '%s', "
                            "rig '%s' or size %dx%d", path, split, rig, w, h);
    c->split = (gs_synth_split)k;
    c->rig = (gs_synth_rig)r;
    c->identities = ids;
    c->seed = seed;
    c->size = w;
    c->supersample = strncmp(ss, "2x2", 3) == 0 ? 2 : 1;
    const char *kp = strstr(text, "Angle kappa per identity: ");
    if (kp) {
        c->kappa.enabled = 1;
        if (sscanf(kp, "Angle kappa per identity: horizontal %lf +- %lf deg, "
                       "vertical %lf +- %lf deg",
                   &c->kappa.h_mean_deg, &c->kappa.h_sd_deg, &c->kappa.v_mean_deg,
                   &c->kappa.v_sd_deg) != 4)
            return gs_error_set(err, GS_ERR_FORMAT, "dataset: %s: unreadable kappa "
                                "line", path);
    }
    if (first)
        *first = f0;
    if (count)
        *count = cnt;
    gs_synth_scene sc;
    gs_synth_camera cam;
    return gs_synth_gen_scene(c, f0, &sc, &cam, err);
}
