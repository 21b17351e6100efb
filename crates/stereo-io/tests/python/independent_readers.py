"""Reads stereo-io's exports the way the popular loaders do, with OpenCV and Pillow only.

usage: independent_readers.py EXPORTS OUT

EXPORTS holds one folder per export target (crestereo, kitti2012, kitti2015, middlebury). For
every sample found the way that layout's loaders find them, OUT/<target>/<n>_{left,right,disp}.npy
receive float32 arrays (images H x W x 3 in RGB; disparity H x W with NaN where the format's
own rule says "no data"), plus OUT/<target>/names.txt. Also makes OUT/jpeg/: real-looking JPEGs
written by OpenCV (4:2:0 and 4:4:4) and their OpenCV decodes, and checks that Pillow decodes
every JPEG to the same pixels. Prints one JSON line of facts the Rust side checks.
"""
import glob
import json
import os
import sys

import cv2
import numpy as np
from PIL import Image

JPEG_MAGIC = b"\xff\xd8\xff"


def rgb_cv2(path):
    img = cv2.imread(path, cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"OpenCV cannot read {path}")
    return img[:, :, ::-1]


def rgb_pil(path):
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def png16_disparity(path, scale):
    """KITTI devkit / CREStereo rule: uint16 / scale, 0 = no ground truth."""
    raw = np.asarray(Image.open(path))
    if raw.dtype != np.uint16 and raw.dtype != np.int32:
        raise SystemExit(f"{path}: disparity PNG is {raw.dtype}, expected 16-bit")
    d = raw.astype(np.float32) / scale
    d[raw == 0] = np.nan
    return d


def pfm_disparity(path):
    """Middlebury rule: inf = unknown. OpenCV reads PFM (and flips its bottom-up rows)."""
    d = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if d is None:
        raise SystemExit(f"OpenCV cannot read {path}")
    d = d.astype(np.float32)
    d[~np.isfinite(d)] = np.nan
    return d


def save(out, n, left, right, disp):
    np.save(os.path.join(out, f"{n}_left.npy"), np.ascontiguousarray(left, dtype=np.float32))
    np.save(os.path.join(out, f"{n}_right.npy"), np.ascontiguousarray(right, dtype=np.float32))
    np.save(os.path.join(out, f"{n}_disp.npy"), np.ascontiguousarray(disp, dtype=np.float32))


def crestereo(root, out, facts):
    # The release's loader: a recursive glob of *_left.jpg, the prefix cut at the last "_".
    lefts = sorted(glob.glob(os.path.join(root, "**", "*_left.jpg"), recursive=True))
    # The popular loaders list the four category folders one by one.
    listed = []
    for category in ["tree", "shapenet", "reflective", "hole"]:
        listed += [f for f in os.listdir(os.path.join(root, category)) if f.endswith("_left.jpg")]
    facts["crestereo_listed_by_category"] = len(listed)
    names = []
    for n, left in enumerate(lefts):
        prefix = left[: left.rindex("_")]
        right, disp = prefix + "_right.jpg", prefix + "_left.disp.png"
        for p in (left, right):
            with open(p, "rb") as f:
                if f.read(3) != JPEG_MAGIC:
                    raise SystemExit(f"{p} is not a JPEG")
            if not (rgb_pil(p) == rgb_cv2(p)).all():
                raise SystemExit(f"Pillow and OpenCV disagree on {p}")
        save(out, n, rgb_cv2(left), rgb_cv2(right), png16_disparity(disp, 32.0))
        names.append(os.path.relpath(prefix, root))
    return names


def kitti(root, out, left_dir, right_dir, disp_dir):
    lefts = sorted(glob.glob(os.path.join(root, "training", left_dir, "*_10.png")))
    names = []
    for n, left in enumerate(lefts):
        right = left.replace(left_dir, right_dir)
        disp = left.replace(left_dir, disp_dir)
        save(out, n, rgb_pil(left), rgb_pil(right), png16_disparity(disp, 256.0))
        names.append(os.path.basename(left))
    return names


def middlebury(root, out, facts):
    # torchvision's Middlebury2014Stereo layout: Middlebury2014/<split>/<scene>-perfect/.
    scenes = sorted(glob.glob(os.path.join(root, "Middlebury2014", "train", "*-perfect")))
    names = []
    for n, scene in enumerate(scenes):
        save(out, n, rgb_pil(os.path.join(scene, "im0.png")), rgb_pil(os.path.join(scene, "im1.png")), pfm_disparity(os.path.join(scene, "disp0.pfm")))
        calib = dict(line.split("=", 1) for line in open(os.path.join(scene, "calib.txt")).read().split("\n") if "=" in line)
        cam0 = [float(v) for v in calib["cam0"].strip("[]").replace(";", " ").split()]
        facts.setdefault("middlebury_calib", []).append({"f": cam0[0], "cx": cam0[2], "cy": cam0[5], "baseline_mm": float(calib["baseline"]), "width": int(calib["width"]), "height": int(calib["height"])})
        names.append(os.path.basename(scene))
    return names


def real_looking(rng, h, w):
    """Shaded surfaces, a textured patch, sharp edges and sensor noise."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.empty((h, w, 3), np.float32)
    for c in range(3):
        img[:, :, c] = 60 + 120 * (x / w) * (c + 1) / 3 + 40 * np.sin(y / (5 + 3 * c)) * np.cos(x / 7)
    img[h // 4 : h // 2, w // 3 : 2 * w // 3] = rng.uniform(0, 255, 3)
    img += 30 * (rng.random((h, w, 1)) > 0.97)
    img += rng.normal(0, 6, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def jpeg_corpus(out, facts):
    rng = np.random.default_rng(15)
    made = []
    for i in range(10):
        h, w = 61 + 7 * i, 83 + 5 * i
        img = real_looking(rng, h, w)
        sampling = cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420 if i % 2 == 0 else cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444
        quality = 95 if i < 6 else 85
        name = f"photo{i}_{'420' if i % 2 == 0 else '444'}q{quality}"
        path = os.path.join(out, name + ".jpg")
        cv2.imwrite(path, img[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, sampling])
        decoded = rgb_cv2(path)
        if not (rgb_pil(path) == decoded).all():
            raise SystemExit(f"Pillow and OpenCV disagree on {path}")
        np.save(os.path.join(out, name + ".npy"), decoded.astype(np.float32))
        made.append(name)
    facts["jpegs"] = made


def main():
    exports, out = sys.argv[1], sys.argv[2]
    facts = {"opencv": cv2.__version__, "pillow": Image.__version__}
    readers = {
        "crestereo": lambda r, o: crestereo(r, o, facts),
        "kitti2012": lambda r, o: kitti(r, o, "colored_0", "colored_1", "disp_occ"),
        "kitti2015": lambda r, o: kitti(r, o, "image_2", "image_3", "disp_occ_0"),
        "middlebury": lambda r, o: middlebury(r, o, facts),
    }
    for target, read in readers.items():
        root = os.path.join(exports, target)
        if not os.path.isdir(root):
            continue
        dst = os.path.join(out, target)
        os.makedirs(dst, exist_ok=True)
        names = read(root, dst)
        with open(os.path.join(dst, "names.txt"), "w") as f:
            f.write("\n".join(names))
        facts[target] = len(names)
    os.makedirs(os.path.join(out, "jpeg"), exist_ok=True)
    jpeg_corpus(os.path.join(out, "jpeg"), facts)
    print(json.dumps(facts))


if __name__ == "__main__":
    main()
