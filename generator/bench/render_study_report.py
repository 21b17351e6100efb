"""The report phase of render_study.py: metrics, table, Pareto plot, recommended default.

Runs in the study venv (numpy, scikit-image, OpenCV, OpenEXR, matplotlib, pinned in
render_study.PINS). Images are the 16-bit sRGB PNGs the render phases saved (view transform
Standard, as the dataset's 8-bit PNGs), compared in [0, 1].

- PSNR: from the mean squared error over all pixels and channels of a category's images against
  the reference (the mean of the two reference halves). `PSNR*` subtracts the reference's own
  noise, estimated from its halves: E|a-b|^2 / 4 is the noise variance of their mean.
- SSIM: scikit-image's structural_similarity (Gaussian window, sigma 1.5, channel mean), averaged.
- L/R: mean absolute difference (8-bit levels) between a left pixel and the right image sampled
  bilinearly at x - d, over pixels whose match is visible (left/right disparities agree within
  0.5 px). View-dependent shading (gloss, glass) makes even the reference disagree; what matters
  is how much a setting adds to the reference's figure.
- Noise correlation: Pearson's r between the two views' residual noise (a render minus the
  reference of its view, every channel), at the same pixel position (where one Cycles seed for
  both views puts the same sampling pattern) and at the stereo match (x - d, nearest pixel, over
  pixels whose match is visible). Pooled over a category's scenes.
"""

import json
import math
import os

import cv2
import numpy as np
import OpenEXR
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

# A setting is acceptable as a default when, in every category, it is no worse than the old
# default by more than these margins.
PSNR_MARGIN_DB = 0.5
SSIM_MARGIN = 0.005
LR_MARGIN = 0.10  # 8-bit levels of mean L/R disagreement


def read_png(path):
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RuntimeError("cannot read %s" % path)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img[:, :, ::-1].astype(np.float64) / scale


def read_disp(path):
    with OpenEXR.File(path) as f:
        ch = f.channels()
        return ch["Y"].pixels.astype(np.float64), ch["valid"].pixels.astype(np.float64) > 0.5


def visible_matches(d_left, v_left, d_right, v_right):
    """Per left pixel: its row, the continuous right column x - d, the nearest right column, and
    whether the match is visible (inside the right view, left/right disparities within 0.5 px)."""
    h, w = d_left.shape
    ys, xs = np.mgrid[0:h, 0:w]
    xr = xs - d_left
    ok = v_left & np.isfinite(xr) & (xr >= 0) & (xr <= w - 1)
    near = np.clip(np.rint(np.where(ok, xr, 0)), 0, w - 1).astype(int)
    ok &= v_right[ys, near] & (np.abs(d_right[ys, near] - d_left) < 0.5)
    return ys, np.where(ok, xr, 0), near, ok


def lr_disagreement(left, right, d_left, v_left, d_right, v_right):
    ys, xr, _, ok = visible_matches(d_left, v_left, d_right, v_right)
    w = d_left.shape[1]
    xi = np.clip(np.floor(xr), 0, w - 2).astype(int)
    t = np.clip(xr - xi, 0, 1)
    sampled = right[ys, xi] * (1 - t)[..., None] + right[ys, xi + 1] * t[..., None]
    diff = np.abs(left - sampled).mean(axis=2)[ok]
    return float(diff.mean() * 255.0), int(ok.sum())


def noise_pairs(res_left, res_right, gt):
    """The residuals paired at the same pixel and at the stereo match, flattened over channels."""
    ys, _, near, ok = visible_matches(*gt)
    xs = np.nonzero(ok)[1]
    same = (res_left.reshape(-1), res_right.reshape(-1))
    match = (res_left[ys[ok], xs].reshape(-1), res_right[ys[ok], near[ok]].reshape(-1))
    return same, match


def pearson(pairs):
    a = np.concatenate([p[0] for p in pairs])
    b = np.concatenate([p[1] for p in pairs])
    if a.size < 2 or a.std() == 0 or b.std() == 0:
        return None  # JSON null: no noise to correlate
    return float(np.corrcoef(a, b)[0, 1])


def fmt_r(r):
    return "-" if r is None else "%.3f" % r


def psnr(mse):
    return 10 * math.log10(1.0 / mse) if mse > 0 else float("inf")


def pareto(points):
    """Indices of the points no other point beats in both time (lower) and PSNR (higher)."""
    front = []
    for i, (t, q) in enumerate(points):
        if not any((t2 <= t and q2 >= q) and (t2 < t or q2 > q) for j, (t2, q2) in enumerate(points) if j != i):
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def report(args, names, refs, candidates, old_default):
    work = args.work
    with open(os.path.join(work, "scenes.json")) as f:
        scenes = json.load(f)
    times = {}
    with open(os.path.join(work, "times.jsonl")) as f:
        for line in f:
            r = json.loads(line)
            times[(r["setting"], r["id"], r["view"])] = r

    def rendered(name):
        return all(os.path.exists(os.path.join(work, "renders", name, s["category"], "%s_%s.png" % (s["id"], v))) for s in scenes for v in ("left", "right"))

    missing = [n for n in names if not rendered(n)]
    if missing:
        print("report: left out (not rendered for every scene yet): %s" % ", ".join(missing))
    names = [n for n in names if n not in missing]

    def img(setting, s, view):
        return read_png(os.path.join(work, "renders", setting, s["category"], "%s_%s.png" % (s["id"], view)))

    cats = sorted({s["category"] for s in scenes})
    ref, ref_noise, ref_lr, gt = {}, {}, {}, {}
    conv = {c: [] for c in cats}
    for s in scenes:
        base = os.path.join(work, "base", s["category"], s["id"])
        gt[s["id"]] = read_disp(base + "_left.disp.exr") + read_disp(base + "_right.disp.exr")
        for view in ("left", "right"):
            a, b = img("ref-a", s, view), img("ref-b", s, view)
            ref[(s["id"], view)] = (a + b) / 2
            mse_ab = float(((a - b) ** 2).mean())
            ref_noise[(s["id"], view)] = mse_ab / 4
            conv[s["category"]].append(mse_ab)
        ref_lr[s["id"]] = lr_disagreement(ref[(s["id"], "left")], ref[(s["id"], "right")], *gt[s["id"]])[0]

    # Our pooled PSNR uses the same formula as scikit-image's per image: check on every reference half.
    psnr_diffs = []
    for s in scenes:
        for view in ("left", "right"):
            a, r = img("ref-a", s, view), ref[(s["id"], view)]
            psnr_diffs.append(abs(psnr(float(((a - r) ** 2).mean())) - peak_signal_noise_ratio(r, a, data_range=1.0)))

    rows = []
    for name in names:
        for cat in cats:
            sc = [s for s in scenes if s["category"] == cat]
            mses, noise, ssims, lrs, rlrs, cpu, wall = [], [], [], [], [], [], []
            same_pairs, match_pairs = [], []
            for s in sc:
                views = {}
                for view in ("left", "right"):
                    x = img(name, s, view)
                    views[view] = x
                    r = ref[(s["id"], view)]
                    mses.append(float(((x - r) ** 2).mean()))
                    noise.append(ref_noise[(s["id"], view)])
                    ssims.append(structural_similarity(x, r, channel_axis=2, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False))
                    t = times[(name, s["id"], view)]
                    cpu.append(t["cpu_s"])
                    wall.append(t["wall_s"])
                lrs.append(lr_disagreement(views["left"], views["right"], *gt[s["id"]])[0])
                same, match = noise_pairs(views["left"] - ref[(s["id"], "left")], views["right"] - ref[(s["id"], "right")], gt[s["id"]])
                same_pairs.append(same)
                match_pairs.append(match)
                rlrs.append(ref_lr[s["id"]])
            mse, nse = float(np.mean(mses)), float(np.mean(noise))
            rows.append({
                "setting": name,
                "category": cat,
                "cpu_s_per_view": float(np.mean(cpu)),
                "wall_s_per_view": float(np.mean(wall)),
                "psnr_db": psnr(mse),
                "psnr_corrected_db": psnr(max(mse - nse, 1e-12)),
                "ssim": float(np.mean(ssims)),
                "lr_disagreement": float(np.mean(lrs)),
                "lr_disagreement_reference": float(np.mean(rlrs)),
                "noise_correlation_same_pixel": pearson(same_pairs),
                "noise_correlation_stereo_match": pearson(match_pairs),
                "settings": candidates[name],
            })

    convergence = {c: {"psnr_half_vs_half_db": psnr(float(np.mean(v))), "reference_noise_psnr_db": psnr(float(np.mean(v)) / 4)} for c, v in conv.items()}
    by = {(r["setting"], r["category"]): r for r in rows}

    # The recommendation: the cheapest setting (total CPU time over all categories) that is within
    # the margins of the old default in every category.
    recommended, per_category = None, {}
    if old_default in names:
        def ok(name, cat):
            r, d = by[(name, cat)], by[(old_default, cat)]
            return (r["psnr_db"] >= d["psnr_db"] - PSNR_MARGIN_DB and r["ssim"] >= d["ssim"] - SSIM_MARGIN
                    and r["lr_disagreement"] <= d["lr_disagreement"] + LR_MARGIN)

        cost = lambda name: sum(by[(name, c)]["cpu_s_per_view"] for c in cats)
        # A default renders each view with its own seed: the shared-seed settings are comparisons.
        eligible = [n for n in names if not candidates[n].get("shared_seed")]
        passing = [n for n in eligible if all(ok(n, c) for c in cats)]
        recommended = min(passing, key=cost) if passing else None
        for c in cats:
            p = [n for n in eligible if ok(n, c)]
            per_category[c] = min(p, key=lambda n: by[(n, c)]["cpu_s_per_view"]) if p else None

    fronts = {}
    for c in cats:
        pts = [(by[(n, c)]["cpu_s_per_view"], by[(n, c)]["psnr_db"]) for n in names]
        fronts[c] = [names[i] for i in pareto(pts)]

    out = {
        "size": args.size,
        "scenes": scenes,
        "reference_samples": args.reference_samples,
        "reference_convergence": convergence,
        "psnr_check": {"against": "skimage.metrics.peak_signal_noise_ratio", "images": len(psnr_diffs), "max_abs_difference_db": max(psnr_diffs)},
        "margins": {"psnr_db": PSNR_MARGIN_DB, "ssim": SSIM_MARGIN, "lr_levels": LR_MARGIN},
        "old_default": old_default,
        "recommended": recommended,
        "recommended_per_category": per_category,
        "pareto_front": fronts,
        "rows": rows,
    }

    lines = ["# Render settings study (%s, %d scenes, reference %d samples in two halves)" % (args.size, len(scenes), args.reference_samples), ""]
    lines.append("Reference convergence (the two halves against each other; noise of their mean):")
    for c, v in convergence.items():
        lines.append("- %s: half vs half %.1f dB, reference noise %.1f dB PSNR" % (c, v["psnr_half_vs_half_db"], v["reference_noise_psnr_db"]))
    lines.append("")
    for c in cats:
        lines.append("## %s" % c)
        lines.append("")
        lines.append("| setting | CPU s/view | wall s/view | PSNR dB | PSNR* dB | SSIM | L/R (ref) | noise r: pixel, match | front |")
        lines.append("|---|---|---|---|---|---|---|---|---|")
        for n in sorted(names, key=lambda n: by[(n, c)]["cpu_s_per_view"]):
            r = by[(n, c)]
            lines.append("| %s%s | %.2f | %.2f | %.2f | %.2f | %.4f | %.2f (%.2f) | %s, %s | %s |" % (
                n, " (old default)" if n == old_default else "", r["cpu_s_per_view"], r["wall_s_per_view"], r["psnr_db"],
                r["psnr_corrected_db"], r["ssim"], r["lr_disagreement"], r["lr_disagreement_reference"],
                fmt_r(r["noise_correlation_same_pixel"]), fmt_r(r["noise_correlation_stereo_match"]), "*" if n in fronts[c] else ""))
        lines.append("")
    lines.append("Within %.1f dB PSNR, %.3f SSIM and %.2f levels L/R of the old default (%s) in every category, cheapest: **%s**" % (
        PSNR_MARGIN_DB, SSIM_MARGIN, LR_MARGIN, old_default, recommended))
    lines.append("Per category: " + ", ".join("%s %s" % kv for kv in per_category.items()))
    if per_category and all(per_category.values()):
        # What a recipe with each category's pick (`render = {...}` in its [[categories]] table)
        # spends on a mix of the categories in equal shares, against the old default everywhere.
        picked = sum(by[(n, c)]["cpu_s_per_view"] for c, n in per_category.items()) / len(cats)
        old = sum(by[(old_default, c)]["cpu_s_per_view"] for c in cats) / len(cats)
        out["per_category_mix_cpu_s_per_view"] = {"picks": picked, "old_default": old}
        lines.append("Each category with its pick, equal shares: %.2f CPU s per view against %.2f with %s everywhere (%+.1f%%)" % (
            picked, old, old_default, 100.0 * (picked / old - 1.0)))
    with open(os.path.join(work, "results.json"), "w") as f:
        json.dump(out, f, indent=1)
    text = "\n".join(lines) + "\n"
    with open(os.path.join(work, "results.md"), "w") as f:
        f.write(text)
    print(text)
    plot(work, names, cats, by, fronts, old_default, recommended)


def plot(work, names, cats, by, fronts, old_default, recommended):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6), dpi=110)
    for i, c in enumerate(cats):
        colour = "C%d" % i
        xs = [by[(n, c)]["cpu_s_per_view"] for n in names]
        ys = [by[(n, c)]["psnr_db"] for n in names]
        ax.scatter(xs, ys, s=14, color=colour, alpha=0.35)
        fx = [by[(n, c)]["cpu_s_per_view"] for n in fronts[c]]
        fy = [by[(n, c)]["psnr_db"] for n in fronts[c]]
        ax.plot(fx, fy, "-o", color=colour, ms=4, label="%s (Pareto front)" % c)
        for n in fronts[c]:
            ax.annotate(n, (by[(n, c)]["cpu_s_per_view"], by[(n, c)]["psnr_db"]), fontsize=6, xytext=(3, 2), textcoords="offset points")
        for n, marker in ((old_default, "s"), (recommended, "*")):
            if n:
                ax.scatter([by[(n, c)]["cpu_s_per_view"]], [by[(n, c)]["psnr_db"]], marker=marker, s=90, facecolors="none", edgecolors=colour)
    ax.set_xscale("log")
    ax.set_xlabel("CPU seconds per view (all Cycles threads)")
    ax.set_ylabel("PSNR against the reference (dB)")
    ax.set_title("Render settings: cost against error (square: old default %s, star: chosen %s)" % (old_default, recommended), fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(work, "pareto.png"))
