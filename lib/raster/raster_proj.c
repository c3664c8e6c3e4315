/* Fast path projection and its gradient, L (8 or 16) Gaussians per vector: the
 * formulas of raster.c's project_one and project_backward_one (the scalar
 * path's, which document them) with branches turned into lane selects.
 * Included by raster_tiles.c, so it is built once per instruction set and
 * uses its vector helpers. Every lane runs the same instructions whatever
 * its neighbours, so the results do not depend on how Gaussians are split
 * into chunks or threads. */

/* No fused multiply-adds here (the AVX2 build contracts elsewhere): the
 * determinant cancels for thin Gaussians, and with the scalar path's
 * rounding the two paths' images stay as close as the compositing alone
 * makes them (alpha within 4e-7 instead of 1.5e-6 on the path tests). */
#if defined(__clang__)
#pragma clang fp contract(off)
#else
#pragma GCC push_options
#pragma GCC optimize("fp-contract=off")
#endif

/* exp(x) for any x: vexp_neg's reduction and polynomial (VEXP_REDUCED,
 * raster_tiles.c), expanded here without fused multiply-adds; +inf above
 * 88.37, 0 below -87.33 (no denormal results). */
static inline vf vexp_any(vf x)
{
    vi big = x > splat(88.3762626647949f), small = x < splat(-87.3365447504f);
    x = vmin(vmax(x, splat(-87.0f)), splat(88.0f));
    vf e;
    VEXP_REDUCED(x, e);
    vf y = vsel(big, splat(INFINITY), e);
    return vsel(small, splat(0.0f), y);
}

/* ln(x) for normal positive x (Cephes' reduction to [sqrt(1/2), sqrt(2))
 * and polynomial, a few ulp); callers keep other lanes out of the result. */
static inline vf vlog_pos(vf x)
{
    vi bits;
    memcpy(&bits, &x, sizeof bits);
    vi e = ((bits >> 23) & 0xff) - 126;
    bits = (bits & 0x007fffff) | 0x3f000000; /* mantissa in [0.5, 1) */
    vf m;
    memcpy(&m, &bits, sizeof m);
    vi lo = m < splat(0.707106781186547524f);
    e += lo; /* true is -1 */
    vf z = vsel(lo, m + m, m) - splat(1.0f);
    vf ef = __builtin_convertvector(e, vf);
    vf p = splat(7.0376836292e-2f);
    p = p * z + splat(-1.1514610310e-1f);
    p = p * z + splat(1.1676998740e-1f);
    p = p * z + splat(-1.2420140846e-1f);
    p = p * z + splat(1.4249322787e-1f);
    p = p * z + splat(-1.6668057665e-1f);
    p = p * z + splat(2.0000714765e-1f);
    p = p * z + splat(-2.4999993993e-1f);
    p = p * z + splat(3.3333331174e-1f);
    vf z2 = z * z;
    vf y = p * z * z2 + ef * splat(-2.12194440e-4f) - splat(0.5f) * z2;
    return z + y + ef * splat(0.693359375f);
}

/* Square root per lane (correctly rounded, as sqrtf). */
static inline vf vsqrt(vf x)
{
#if L == 16 && defined(__AVX512F__)
    return (vf)_mm512_sqrt_ps((__m512)x);
#elif L == 8 && defined(__AVX__)
    return (vf)_mm256_sqrt_ps((__m256)x);
#elif L == 8 && defined(__SSE2__)
    vf4 lo = __builtin_shufflevector(x, x, 0, 1, 2, 3), hi = __builtin_shufflevector(x, x, 4, 5, 6, 7);
    lo = (vf4)_mm_sqrt_ps((__m128)lo);
    hi = (vf4)_mm_sqrt_ps((__m128)hi);
    return __builtin_shufflevector(lo, hi, 0, 1, 2, 3, 4, 5, 6, 7);
#else
    lanes l = {x};
    for (int j = 0; j < L; j++)
        l.f[j] = sqrtf(l.f[j]);
    return l.v;
#endif
}

static inline vi vfinite(vf x)
{
    return (x - x) == splat(0.0f);
}

static inline vf vabs(vf x)
{
    return (vf)((vi)x & 0x7fffffff);
}

/* Lane j of v = a[j * stride + k] for the n <= 8 Gaussians from a; zeros
 * past n. */
static inline vf gather_aos(const float *a, int stride, int k, int n)
{
    lanes l = {splat(0.0f)};
    for (int j = 0; j < n; j++)
        l.f[j] = a[(size_t)j * (size_t)stride + (size_t)k];
    return l.v;
}

/* 8 Gaussians in the camera frame (raster.c's camera_gaussian). */
typedef struct {
    vf x, y, z;
    vf R[9], qn[4], s[3], Sc[6]; /* Sc: 00 01 02 11 12 22 */
    vf j00, j02, j11, j12, tx, ty;
    vi clamp_x, clamp_y, in_range, qzero;
} vcam;

static inline void vquat_rot(vcam *c, const float *q, int n)
{
    vf w = gather_aos(q, 4, 0, n), x = gather_aos(q, 4, 1, n);
    vf y = gather_aos(q, 4, 2, n), z = gather_aos(q, 4, 3, n);
    vf m = vmax(vmax(vabs(w), vabs(x)), vmax(vabs(y), vabs(z)));
    c->qzero = ~(m > splat(0.0f));
    vf d = vsel(c->qzero, splat(1.0f), m);
    w = vsel(c->qzero, splat(1.0f), w / d), x = x / d, y = y / d, z = z / d;
    vf inv = splat(1.0f) / vsqrt(w * w + x * x + y * y + z * z);
    w *= inv, x *= inv, y *= inv, z *= inv;
    c->qn[0] = w, c->qn[1] = x, c->qn[2] = y, c->qn[3] = z;
    vf one = splat(1.0f), two = splat(2.0f);
    c->R[0] = one - two * (y * y + z * z), c->R[1] = two * (x * y - w * z);
    c->R[2] = two * (x * z + w * y), c->R[3] = two * (x * y + w * z);
    c->R[4] = one - two * (x * x + z * z), c->R[5] = two * (y * z - w * x);
    c->R[6] = two * (x * z - w * y), c->R[7] = two * (y * z + w * x);
    c->R[8] = one - two * (x * x + y * y);
}

static inline void vto_camera(const gs_raster *r, int i0, int n, vcam *c)
{
    const float *V = r->cam.viewmat;
    const float *p = r->g.means + 3 * (size_t)i0;
    vf px = gather_aos(p, 3, 0, n), py = gather_aos(p, 3, 1, n), pz = gather_aos(p, 3, 2, n);
    c->x = splat(V[0]) * px + splat(V[1]) * py + splat(V[2]) * pz + splat(V[3]);
    c->y = splat(V[4]) * px + splat(V[5]) * py + splat(V[6]) * pz + splat(V[7]);
    c->z = splat(V[8]) * px + splat(V[9]) * py + splat(V[10]) * pz + splat(V[11]);
    vi lane = {0, 1, 2, 3, 4, 5, 6, 7};
    c->in_range = (c->z >= splat(GS_RASTER_NEAR)) & (c->z <= splat(GS_RASTER_FAR)) &
                  (lane < (vi){0} + n);
    vquat_rot(c, r->g.quats + 4 * (size_t)i0, n);
    const float *ls = r->g.log_scales + 3 * (size_t)i0;
    for (int k = 0; k < 3; k++)
        c->s[k] = vexp_any(gather_aos(ls, 3, k, n));
    /* M = R S, WM = V M, Sc = WM WM^T */
    vf WM[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            WM[i * 3 + j] = splat(V[i * 4 + 0]) * c->R[j] * c->s[j] +
                            splat(V[i * 4 + 1]) * c->R[3 + j] * c->s[j] +
                            splat(V[i * 4 + 2]) * c->R[6 + j] * c->s[j];
    static const int pi[6] = {0, 0, 0, 1, 1, 2}, pj[6] = {0, 1, 2, 1, 2, 2};
    for (int e = 0; e < 6; e++) {
        const vf *u = WM + 3 * pi[e], *v = WM + 3 * pj[e];
        c->Sc[e] = u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    }
    const float *lim = r->clamp_lim;
    vf zs = vsel(c->in_range, c->z, splat(1.0f)); /* keep other lanes finite */
    vf u = c->x / zs, v = c->y / zs;
    c->clamp_x = (u < splat(-lim[1])) | (u > splat(lim[0]));
    c->clamp_y = (v < splat(-lim[3])) | (v > splat(lim[2]));
    c->tx = zs * vmin(vmax(u, splat(-lim[1])), splat(lim[0]));
    c->ty = zs * vmin(vmax(v, splat(-lim[3])), splat(lim[2]));
    vf rz = splat(1.0f) / zs, rz2 = rz * rz;
    c->j00 = splat(r->cam.fx) * rz;
    c->j02 = -splat(r->cam.fx) * c->tx * rz2;
    c->j11 = splat(r->cam.fy) * rz;
    c->j12 = -splat(r->cam.fy) * c->ty * rz2;
}

/* ceil(x) for the radius: exact for |x| < 2^23, x itself beyond (already
 * an integer, or inf/NaN, which the caller culls). */
static inline vf vceil(vf x)
{
    vi small = vabs(x) < splat(8388608.0f);
    vf xs = vsel(small, x, splat(0.0f));
    vf t = __builtin_convertvector(__builtin_convertvector(xs, vi), vf);
    t += vsel(t < xs, splat(1.0f), splat(0.0f));
    return vsel(small, t, x);
}

/* floor(x) for |x| < 2^31 (callers clamp first). */
static inline vf vfloor(vf x)
{
    vf t = __builtin_convertvector(__builtin_convertvector(x, vi), vf);
    return t - vsel(t > x, splat(1.0f), splat(0.0f));
}

/* Tiles [lo, hi) whose pixel centres [16 t + 0.49, 16 t + 15.51] meet
 * [x0, x1], within [lo, hi) (raster.c's centre_range). */
static inline void vcentre_range(vf x0, vf x1, vf *lo, vf *hi)
{
    const vf rT = splat(1.0f / (float)TS);
    vf f0 = vmin(vmax((x0 + splat(0.49f)) * rT - splat(1.0f), *lo), *hi);
    vf f1 = vmin(vmax((x1 - splat(0.49f)) * rT + splat(1.0f), f0), *hi);
    *lo = -vfloor(-f0); /* ceil */
    *hi = vmax(vfloor(f1), *lo);
}

/* The tile box of a splat: gsplat's radius box [x0, x1) x [y0, y1) (floor
 * and ceil of mean -+ radius over the tile size, clamped to the image's
 * tiles), narrowed to the tiles that the bounding box of its sigma <= thr
 * ellipse reaches. Values are clamped before rounding, so the conversions
 * stay in range. */
typedef struct {
    vf t[4]; /* x0, x1, y0, y1 */
} vbox;

static inline vbox vsplat_tiles(const gs_raster *r, vf mx, vf my, vf rad, vf ex, vf ey)
{
    vbox box;
    const vf rT = splat(1.0f / (float)TS), zero = splat(0.0f);
    vf tx = splat((float)r->tiles_x), ty = splat((float)r->tiles_y);
    vf big_x = tx + splat(1.0f), big_y = ty + splat(1.0f);
    box.t[0] = vmin(vmax(vfloor(vmax((mx - rad) * rT, splat(-1.0f))), zero), tx);
    box.t[1] = vmin(vmax(-vfloor(-vmin((mx + rad) * rT, big_x)), zero), tx);
    box.t[2] = vmin(vmax(vfloor(vmax((my - rad) * rT, splat(-1.0f))), zero), ty);
    box.t[3] = vmin(vmax(-vfloor(-vmin((my + rad) * rT, big_y)), zero), ty);
    vcentre_range(mx - ex, mx + ex, &box.t[0], &box.t[1]);
    vcentre_range(my - ey, my + ey, &box.t[2], &box.t[3]);
    return box;
}

/* Projects Gaussians [i0, i1) (i0 a multiple of 8) into r->proj and
 * r->splats, and the tile boxes of the visible ones. */
static void project_fast(gs_raster *r, int i0, int i1)
{
    gs_proj *P = &r->proj;
    const gs_camera *cam = &r->cam;
    for (int b = i0; b < i1; b += L) {
        int n = i1 - b < L ? i1 - b : L;
        vcam c;
        vto_camera(r, b, n, &c);
        const vf *Sc = c.Sc;
        vf s00 = c.j00 * c.j00 * Sc[0] + splat(2.0f) * c.j00 * c.j02 * Sc[2] +
                 c.j02 * c.j02 * Sc[5];
        vf s11 = c.j11 * c.j11 * Sc[3] + splat(2.0f) * c.j11 * c.j12 * Sc[4] +
                 c.j12 * c.j12 * Sc[5];
        vf s01 = c.j00 * c.j11 * Sc[1] + c.j00 * c.j12 * Sc[2] + c.j02 * c.j11 * Sc[4] +
                 c.j02 * c.j12 * Sc[5];
        vf det0 = s00 * s11 - s01 * s01;
        s00 += splat(GS_RASTER_EPS2D);
        s11 += splat(GS_RASTER_EPS2D);
        vf det = s00 * s11 - s01 * s01;
        vi ok = c.in_range & (det > splat(0.0f)) & vfinite(det);
        vf inv = splat(1.0f) / vsel(ok, det, splat(1.0f));
        vf a = s11 * inv, bb = -s01 * inv, cc = s00 * inv;
        vf zs = vsel(c.in_range, c.z, splat(1.0f));
        vf mx = splat(cam->fx) * c.x / zs + splat(cam->cx);
        vf my = splat(cam->fy) * c.y / zs + splat(cam->cy);
        vf half = splat(0.5f) * (s00 + s11);
        vf lam = half + vsqrt(vmax(half * half - det, splat(0.01f)));
        vf rad = vceil(splat(3.0f) * vsqrt(lam));
        ok &= vfinite(rad) & vfinite(mx) & vfinite(my) & vfinite(a) & vfinite(bb) & vfinite(cc);
        ok &= (mx + rad > splat(0.0f)) & (mx - rad < splat((float)cam->width)) &
              (my + rad > splat(0.0f)) & (my - rad < splat((float)cam->height));
        vf comp = vsqrt(vmax(det0 * inv, splat(0.0f)));
        vf lo = gather_aos(r->g.opacity_logits + b, 1, 0, n);
        vf op = splat(1.0f) / (splat(1.0f) + vexp_any(-lo));
        if (r->opt.antialiased)
            op *= comp;
        /* Opacity-aware cull: no pixel can reach alpha 1/255. The small
         * margin keeps the test conservative against rounding. log(255 op)
         * > -1e-3 needs 255 op > 0.999, so the logarithm only sees normal
         * inputs. */
        vf op255 = splat(255.0f) * op;
        ok &= op255 > splat(0.99f);
        vf thr = vlog_pos(vsel(ok, op255, splat(1.0f)));
        ok &= thr > splat(-1e-3f);
        thr = thr * splat(1.0001f) + splat(1e-4f);
        vf cdet = a * cc - bb * bb;
        vf ex = vsqrt(vmax(splat(2.0f) * thr * cc / cdet, splat(0.0f))) +
                splat(0.01f);
        vf ey = vsqrt(vmax(splat(2.0f) * thr * a / cdet, splat(0.0f))) +
                splat(0.01f);
        vf z0 = splat(0.0f); /* culled lanes may hold NaN: keep them out */
        vbox box = vsplat_tiles(r, vsel(ok, mx, z0), vsel(ok, my, z0), vsel(ok, rad, z0),
                                vsel(ok, ex, z0), vsel(ok, ey, z0));
        lanes lbox[4] = {{box.t[0]}, {box.t[1]}, {box.t[2]}, {box.t[3]}};
        lanes lmx = {mx}, lmy = {my}, la = {a}, lb = {bb}, lc = {cc}, lz = {c.z}, lop = {op};
        lanes lcomp = {comp}, lrad = {rad}, lthr = {thr}, lex = {ex}, ley = {ey};
        unsigned vis = (unsigned)mask_bits(ok);
        for (int j = 0; j < n; j++) {
            int i = b + j;
            P->radius[i] = 0.0f;
            if (!(vis >> j & 1))
                continue;
            gs_splat *sp = r->splats + i;
            sp->mx = lmx.f[j], sp->my = lmy.f[j];
            sp->a = la.f[j], sp->b = lb.f[j], sp->c = lc.f[j];
            sp->op = lop.f[j], sp->z = lz.f[j], sp->thr = lthr.f[j];
            sp->ex = lex.f[j], sp->ey = ley.f[j];
            P->mean2d[2 * i] = sp->mx, P->mean2d[2 * i + 1] = sp->my;
            P->conic[3 * i] = sp->a, P->conic[3 * i + 1] = sp->b, P->conic[3 * i + 2] = sp->c;
            P->depth[i] = sp->z, P->opacity[i] = sp->op, P->comp[i] = lcomp.f[j];
            P->radius[i] = lrad.f[j];
            for (int k = 0; k < 4; k++)
                sp->tiles[k] = (int32_t)lbox[k].f[j];
        }
    }
}

/* Adds v (n lanes) into a[j * stride + k]. */
static inline void scatter_add(float *a, int stride, int k, vf v, unsigned mask, int n)
{
    lanes l = {v};
    for (int j = 0; j < n; j++)
        if (mask >> j & 1)
            a[(size_t)j * (size_t)stride + (size_t)k] += l.f[j];
}

/* v_Sigma2 (full symmetric 2x2) from the conic and opacity gradients
 * (raster.c's conic_vjp). */
typedef struct {
    vf s[4]; /* 00 01 10 11 */
} vsym2;

static inline vsym2 vconic_vjp(const gs_raster *r, int b, int n)
{
    vsym2 out;
    vf a = gather_aos(r->proj.conic + 3 * (size_t)b, 3, 0, n);
    vf bb = gather_aos(r->proj.conic + 3 * (size_t)b, 3, 1, n);
    vf c = gather_aos(r->proj.conic + 3 * (size_t)b, 3, 2, n);
    const float *vq = r->pgrad.conic + 3 * (size_t)b;
    vf g00 = gather_aos(vq, 3, 0, n), g01 = splat(0.5f) * gather_aos(vq, 3, 1, n);
    vf g11 = gather_aos(vq, 3, 2, n);
    vf pg00 = a * g00 + bb * g01, pg01 = a * g01 + bb * g11;
    vf pg10 = bb * g00 + c * g01, pg11 = bb * g01 + c * g11;
    out.s[0] = -(pg00 * a + pg01 * bb);
    out.s[1] = -(pg00 * bb + pg01 * c);
    out.s[2] = -(pg10 * a + pg11 * bb);
    out.s[3] = -(pg10 * bb + pg11 * c);
    if (!r->opt.antialiased)
        return out;
    vf comp = gather_aos(r->proj.comp + b, 1, 0, n);
    vf lo = gather_aos(r->g.opacity_logits + b, 1, 0, n);
    vf sig = splat(1.0f) / (splat(1.0f) + vexp_any(-lo));
    vf v_comp = gather_aos(r->pgrad.opacity + b, 1, 0, n) * sig;
    vi pos = comp > splat(0.0f);
    vf k = vsel(pos, v_comp * splat(0.5f) / vsel(pos, comp, splat(1.0f)), splat(0.0f));
    vf one = splat(1.0f) - comp * comp, detp = a * c - bb * bb;
    vf eps = splat(GS_RASTER_EPS2D);
    out.s[0] += k * (one * a - eps * detp);
    out.s[1] += k * one * bb;
    out.s[2] += k * one * bb;
    out.s[3] += k * (one * c - eps * detp);
    return out;
}

/* Gradient of the projection of Gaussians [i0, i1) (i0 a multiple of 8)
 * into grads (raster.c's project_backward_one). */
static void project_backward_fast(gs_raster *r, int i0, int i1, gs_gaussian_grads *grads)
{
    const float *V = r->cam.viewmat;
    const float fx = r->cam.fx, fy = r->cam.fy;
    for (int b = i0; b < i1; b += L) {
        int n = i1 - b < L ? i1 - b : L;
        unsigned vis = 0;
        for (int j = 0; j < n; j++)
            vis |= (unsigned)(r->proj.radius[b + j] > 0) << j;
        if (!vis)
            continue;
        vcam cg;
        vto_camera(r, b, n, &cg);
        const vf *Sc6 = cg.Sc;
        vf Sc[9] = {Sc6[0], Sc6[1], Sc6[2], Sc6[1], Sc6[3], Sc6[4], Sc6[2], Sc6[4], Sc6[5]};
        vsym2 vjp = vconic_vjp(r, b, n);
        const vf *vS2 = vjp.s;
        vf zero = splat(0.0f);
        vf Jm[6] = {cg.j00, zero, cg.j02, zero, cg.j11, cg.j12};
        vf vSc[9], JS[6], vJ[6];
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 3; c++)
                vSc[a * 3 + c] = Jm[a] * (vS2[0] * Jm[c] + vS2[1] * Jm[3 + c]) +
                                 Jm[3 + a] * (vS2[2] * Jm[c] + vS2[3] * Jm[3 + c]);
        for (int a = 0; a < 2; a++)
            for (int c = 0; c < 3; c++)
                JS[a * 3 + c] = Jm[a * 3] * Sc[c] + Jm[a * 3 + 1] * Sc[3 + c] +
                                Jm[a * 3 + 2] * Sc[6 + c];
        for (int a = 0; a < 2; a++)
            for (int c = 0; c < 3; c++)
                vJ[a * 3 + c] =
                    splat(2.0f) * (vS2[a * 2] * JS[c] + vS2[a * 2 + 1] * JS[3 + c]);

        /* Camera-space mean gradient: mean2d, depth, and the Jacobian. */
        vf z = vsel(cg.in_range, cg.z, splat(1.0f));
        vf rz = splat(1.0f) / z, rz2 = rz * rz, rz3 = rz2 * rz;
        vf vm0 = gather_aos(r->pgrad.mean2d + 2 * (size_t)b, 2, 0, n);
        vf vm1 = gather_aos(r->pgrad.mean2d + 2 * (size_t)b, 2, 1, n);
        vf vfx = splat(fx), vfy = splat(fy);
        vf vx = vm0 * vfx * rz, vy = vm1 * vfy * rz;
        vf vz = -(vm0 * vfx * cg.x + vm1 * vfy * cg.y) * rz2 +
                gather_aos(r->pgrad.depth + b, 1, 0, n);
        vz += -vfx * rz2 * vJ[0] - vfy * rz2 * vJ[4];
        /* j02 = -fx tx / z^2 with tx = x unclamped, z * lim when clamped. */
        vz += vsel(cg.clamp_x, vfx * cg.tx * rz3 * vJ[2],
                   splat(2.0f) * vfx * cg.x * rz3 * vJ[2]);
        vx += vsel(cg.clamp_x, zero, -vfx * rz2 * vJ[2]);
        vz += vsel(cg.clamp_y, vfy * cg.ty * rz3 * vJ[5],
                   splat(2.0f) * vfy * cg.y * rz3 * vJ[5]);
        vy += vsel(cg.clamp_y, zero, -vfy * rz2 * vJ[5]);
        if (grads->means)
            for (int k = 0; k < 3; k++)
                scatter_add(grads->means + 3 * (size_t)b, 3, k,
                            splat(V[k]) * vx + splat(V[4 + k]) * vy + splat(V[8 + k]) * vz,
                            vis, n);

        /* Sc = V Sigma V^T: v_Sigma = V^T vSc V. Sigma = M M^T, M = R S. */
        vf tmp[9], vSig[9], vM[9];
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 3; c++)
                tmp[a * 3 + c] = vSc[a * 3] * splat(V[c]) + vSc[a * 3 + 1] * splat(V[4 + c]) +
                                 vSc[a * 3 + 2] * splat(V[8 + c]);
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 3; c++)
                vSig[a * 3 + c] = splat(V[a]) * tmp[c] + splat(V[4 + a]) * tmp[3 + c] +
                                  splat(V[8 + a]) * tmp[6 + c];
        const vf *R = cg.R, *s = cg.s;
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 3; c++)
                vM[a * 3 + c] = (vSig[a * 3] + vSig[a]) * R[c] * s[c] +
                                (vSig[a * 3 + 1] + vSig[3 + a]) * R[3 + c] * s[c] +
                                (vSig[a * 3 + 2] + vSig[6 + a]) * R[6 + c] * s[c];
        if (grads->log_scales)
            for (int c = 0; c < 3; c++)
                scatter_add(grads->log_scales + 3 * (size_t)b, 3, c,
                            (vM[c] * R[c] + vM[3 + c] * R[3 + c] + vM[6 + c] * R[6 + c]) * s[c],
                            vis, n);
        unsigned qvis = vis & ~(unsigned)mask_bits(cg.qzero);
        if (grads->quats && qvis) {
            vf vR[9];
            for (int a = 0; a < 9; a++)
                vR[a] = vM[a] * s[a % 3];
            vf w = cg.qn[0], qx = cg.qn[1], qy = cg.qn[2], qz = cg.qn[3], two = splat(2.0f);
            vf vq[4];
            vq[0] = two * (-qz * vR[1] + qy * vR[2] + qz * vR[3] - qx * vR[5] - qy * vR[6] +
                           qx * vR[7]);
            vq[1] = two * (qy * vR[1] + qz * vR[2] + qy * vR[3] - two * qx * vR[4] -
                           w * vR[5] + qz * vR[6] + w * vR[7] - two * qx * vR[8]);
            vq[2] = two * (-two * qy * vR[0] + qx * vR[1] + w * vR[2] + qx * vR[3] +
                           qz * vR[5] - w * vR[6] + qz * vR[7] - two * qy * vR[8]);
            vq[3] = two * (-two * qz * vR[0] - w * vR[1] + qx * vR[2] + w * vR[3] -
                           two * qz * vR[4] + qy * vR[5] + qx * vR[6] + qy * vR[7]);
            vf dot = vq[0] * w + vq[1] * qx + vq[2] * qy + vq[3] * qz;
            const float *q = r->g.quats + 4 * (size_t)b;
            vf q0 = gather_aos(q, 4, 0, n), q1 = gather_aos(q, 4, 1, n);
            vf q2 = gather_aos(q, 4, 2, n), q3 = gather_aos(q, 4, 3, n);
            vf qm = vmax(vmax(vabs(q0), vabs(q1)), vmax(vabs(q2), vabs(q3)));
            qm = vsel(cg.qzero, splat(1.0f), qm);
            q0 /= qm, q1 /= qm, q2 /= qm, q3 /= qm;
            vf inv = splat(1.0f) / (qm * vsqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3));
            for (int k = 0; k < 4; k++)
                scatter_add(grads->quats + 4 * (size_t)b, 4, k, (vq[k] - cg.qn[k] * dot) * inv, qvis, n);
        }
        if (grads->opacity_logits) {
            vf lo = gather_aos(r->g.opacity_logits + b, 1, 0, n);
            vf sig = splat(1.0f) / (splat(1.0f) + vexp_any(-lo));
            vf f = r->opt.antialiased ? gather_aos(r->proj.comp + b, 1, 0, n) : splat(1.0f);
            vf vop = gather_aos(r->pgrad.opacity + b, 1, 0, n);
            scatter_add(grads->opacity_logits + b, 1, 0, vop * f * sig * (splat(1.0f) - sig),
                        vis, n);
        }
    }
}

#if defined(__clang__)
#pragma clang fp contract(on) /* clang's default */
#else
#pragma GCC pop_options
#endif
