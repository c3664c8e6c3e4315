"""Speed against error from the runs of experiments/eval/speed.sh.

usage: speed_table.py OUT_DIR
Reads OUT_DIR/i<iters>_t<threads>_p<percent>_s<scale>_<inc|full>/pairs.csv
(gazesplat eval, method model) and writes OUT_DIR/speed.md (a fit-budget
table and a render-settings table) and OUT_DIR/speed.png (error against
render time for the render settings, error against fit time for the fit
budgets)."""
import csv
import math
import os
import re
import sys

RUN = re.compile(r"i(\d+)_t(\d+)_p(\d+(?:\.\d+)?)_s(\d+(?:\.\d+)?)_(inc|full)")


def mean(xs):
    xs = [x for x in xs if math.isfinite(x)]
    return sum(xs) / len(xs) if xs else float("nan")


def num(v):
    return float(v) if v not in ("", "inf") else float("nan")


def load(path):
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["method"] == "model"]
    fits = {r["input"]: num(r["fit_s"]) for r in rows if r["fit_s"]}

    def col(name, only=None):
        return [num(r[name]) for r in rows
                if only is None or r["head_change"] == only]

    bad = sum(r["status"] != "ok" for r in rows)
    return {
        "pairs": len(rows), "bad": bad,
        "fit_s": mean(list(fits.values())),
        "render_ms": mean(col("render_ms")),
        "render_gaze_ms": mean(col("render_ms", "0")),
        "render_head_ms": mean(col("render_ms", "1")),
        "gaze": mean(col("gaze_err_deg")),
        "psnr": mean(col("psnr")),
        "ssim": mean(col("ssim")),
        "eye_psnr": mean(col("eye_psnr")),
        "id_psnr": mean(col("id_psnr")),
        "fit_psnr": mean(col("fit_psnr")),
    }


def fmt(v, prec):
    return f"{v:.{prec}f}" if math.isfinite(v) else "–"


def runs_in(out):
    runs = []
    for d in sorted(os.listdir(out)):
        m = RUN.fullmatch(d)
        p = os.path.join(out, d, "pairs.csv")
        if not m or not os.path.exists(p):
            continue
        src = os.path.join(out, d, "fits_from")
        reused = os.path.exists(src)
        runs.append({
            "dir": d, "iters": int(m.group(1)), "threads": int(m.group(2)),
            "prune": float(m.group(3)), "scale": float(m.group(4)),
            "mode": m.group(5), "reused": reused, **load(p)})
    return runs


def fit_table(runs):
    rows = [r for r in runs if not r["reused"]]
    rows.sort(key=lambda r: (r["iters"], r["threads"], -r["prune"]))
    lines = ["| fit iterations | threads | pairs | fit s | render ms | "
             "fit PSNR | PSNR | SSIM | eye PSNR | id PSNR | gaze° |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(
            f"| {r['iters']} | {r['threads']} | {r['pairs']} | "
            f"{fmt(r['fit_s'], 1)} | {fmt(r['render_ms'], 1)} | "
            f"{fmt(r['fit_psnr'], 2)} | {fmt(r['psnr'], 2)} | "
            f"{fmt(r['ssim'], 4)} | {fmt(r['eye_psnr'], 2)} | "
            f"{fmt(r['id_psnr'], 2)} | {fmt(r['gaze'], 2)} |")
    return lines


def render_rows(out, runs):
    """The render-settings grid: the reused-fit runs and the runs they
    reused (the exact settings, 100 % / 1 / incremental)."""
    srcs = set()
    for r in runs:
        if r["reused"]:
            with open(os.path.join(out, r["dir"], "fits_from")) as f:
                srcs.add(f.read().strip())
    rows = [r for r in runs if r["reused"] or r["dir"] in srcs]
    rows.sort(key=lambda r: (r["threads"], -r["prune"], -r["scale"],
                             r["mode"] != "inc"))
    return rows


def render_table(rows):
    exact = {r["threads"]: r for r in rows
             if r["prune"] == 100 and r["scale"] == 1 and r["mode"] == "inc"}
    lines = ["| face Gaussians | feature scale | renders | threads | pairs | "
             "render ms | gaze-only ms | head-change ms | images/s | PSNR | "
             "ΔPSNR | SSIM | eye PSNR | id PSNR | gaze° | errors |",
             "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
             "---:|---:|---:|---:|"]
    for r in rows:
        e = exact.get(r["threads"])
        dp = r["psnr"] - e["psnr"] if e else float("nan")
        ips = 1000.0 / r["render_ms"] if r["render_ms"] > 0 else float("nan")
        lines.append(
            f"| {r['prune']:g} % | {r['scale']:g} | {r['mode']} | "
            f"{r['threads']} | {r['pairs']} | {fmt(r['render_ms'], 1)} | "
            f"{fmt(r['render_gaze_ms'], 1)} | {fmt(r['render_head_ms'], 1)} | "
            f"{fmt(ips, 1)} | {fmt(r['psnr'], 2)} | {fmt(dp, 2)} | "
            f"{fmt(r['ssim'], 4)} | {fmt(r['eye_psnr'], 2)} | "
            f"{fmt(r['id_psnr'], 2)} | {fmt(r['gaze'], 2)} | {r['bad']} |")
    return lines


def plot(runs, rows, path):
    import matplotlib
    import matplotlib.ticker
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5))
    markers = {100: "o", 50: "s", 25: "^", 10: "v"}
    colours = {1.0: "tab:blue", 0.75: "tab:orange", 0.5: "tab:green"}
    seen = set()
    for r in rows:
        mk = markers.get(r["prune"], "D")
        col = colours.get(r["scale"], "tab:gray")
        face = col if r["mode"] == "inc" else "none"
        label = f"{r['prune']:g} %, scale {r['scale']:g}, {r['mode']}"
        ax.scatter(r["render_ms"], r["psnr"], marker=mk, edgecolors=col,
                   facecolors=face, s=40,
                   label=None if label in seen else label)
        seen.add(label)
        ax.annotate(f"{r['threads']}t", (r["render_ms"], r["psnr"]),
                    fontsize=6, xytext=(3, 2), textcoords="offset points")
    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("render time per image, ms (log)")
    ax.set_ylabel("PSNR against the ground-truth target, dB")
    ax.set_title("render settings (fits reused)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    fits = [r for r in runs if not r["reused"]]
    for key, label in (("psnr", "PSNR"), ("eye_psnr", "eye PSNR"),
                       ("id_psnr", "id PSNR")):
        bx.plot([r["fit_s"] for r in fits], [r[key] for r in fits], "o",
                label=label)
        for r in fits:
            bx.annotate(f"{r['iters']}it/{r['threads']}t",
                        (r["fit_s"], r[key]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
    bx.set_xlabel("fit time per input, s")
    bx.set_ylabel("dB against the ground-truth target")
    bx.set_title("fit budget")
    bx.grid(alpha=0.3)
    bx.legend(fontsize=7)
    fig.suptitle("gazesplat eval: speed against error (model)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    out = sys.argv[1]
    runs = runs_in(out)
    rows = render_rows(out, runs)
    text = ["## Fit budget", ""] + fit_table(runs)
    text += ["", "## Render settings (fits reused)", ""] + render_table(rows)
    with open(os.path.join(out, "speed.md"), "w") as f:
        f.write("\n".join(text) + "\n")
    print("\n".join(text))
    plot(runs, rows, os.path.join(out, "speed.png"))


if __name__ == "__main__":
    main()
