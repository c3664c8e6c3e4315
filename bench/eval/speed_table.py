"""Speed against error from the runs of bench/eval/speed.sh.

usage: speed_table.py OUT_DIR
Reads OUT_DIR/iters<N>_t<T>/pairs.csv (gazesplat eval, method model) and
writes OUT_DIR/speed.md (one row per setting) and OUT_DIR/speed.png (fit
time against PSNR and eye PSNR)."""
import csv
import math
import os
import re
import sys


def mean(xs):
    xs = [x for x in xs if math.isfinite(x)]
    return sum(xs) / len(xs) if xs else float("nan")


def load(path):
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["method"] == "model"]

    def col(name):
        return [float(r[name]) if r[name] not in ("", "inf") else float("nan")
                for r in rows]

    fits = {}
    for r in rows:
        if r["fit_s"]:
            fits[r["input"]] = float(r["fit_s"])
    return {
        "pairs": len(rows),
        "fit_s": mean(list(fits.values())),
        "render_ms": mean(col("render_ms")),
        "gaze": mean(col("gaze_err_deg")),
        "psnr": mean(col("psnr")),
        "ssim": mean(col("ssim")),
        "eye_psnr": mean(col("eye_psnr")),
        "id_psnr": mean(col("id_psnr")),
        "fit_psnr": mean(col("fit_psnr")),
    }


def main():
    out = sys.argv[1]
    runs = []
    for d in sorted(os.listdir(out)):
        m = re.fullmatch(r"iters(\d+)_t(\d+)", d)
        p = os.path.join(out, d, "pairs.csv")
        if m and os.path.exists(p):
            runs.append((int(m.group(1)), int(m.group(2)), load(p)))
    runs.sort()

    def fmt(v, prec):
        return f"{v:.{prec}f}" if math.isfinite(v) else "–"

    lines = ["| fit iterations | threads | pairs | fit s | render ms | "
             "fit PSNR | PSNR | SSIM | eye PSNR | id PSNR | gaze° |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for it, th, r in runs:
        lines.append(f"| {it} | {th} | {r['pairs']} | {fmt(r['fit_s'], 1)} | "
                     f"{fmt(r['render_ms'], 1)} | {fmt(r['fit_psnr'], 2)} | "
                     f"{fmt(r['psnr'], 2)} | {fmt(r['ssim'], 4)} | "
                     f"{fmt(r['eye_psnr'], 2)} | {fmt(r['id_psnr'], 2)} | "
                     f"{fmt(r['gaze'], 2)} |")
    with open(os.path.join(out, "speed.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    for key, label in (("psnr", "PSNR"), ("eye_psnr", "eye PSNR"),
                       ("id_psnr", "id PSNR")):
        pts = [(r["fit_s"], r[key], it, th) for it, th, r in runs]
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", label=label)
        for x, y, it, th in pts:
            ax.annotate(f"{it}it/{th}t", (x, y), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("fit time per input, s")
    ax.set_ylabel("dB against the ground-truth target")
    ax.set_title("gazesplat eval: fit budget against error (model)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "speed.png"), dpi=110)


if __name__ == "__main__":
    main()
