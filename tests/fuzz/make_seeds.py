"""Regenerates the fuzzers' seed corpora, tests/fuzz/corpus/<target>/, from the bundled data in assets/.

Small files only (a few KB; the largest is a bundled 10 KB JPEG), so that the fuzzers' inputs stay small:
  image/     a bundled silhouette as JPEG (as shipped), and re-encoded through drapelab's own writer in every
             supported format, bit depth and channel layout at full size (256 px: reaches the drape
             measures), at 64 px and at 8 px
  obj/       a tiny Cusick disk (hexagon fan) in the OBJ spellings read_obj accepts, and the coarsest
             bundled template mesh cut to its first rings
  manifest/  the bundled manifest.csv and variants (quoting, BOM, CRLF, optional columns absent)

Run from the repository root after a build (needs the native module):
  PYTHONPATH=addon DRAPELAB_NATIVE_DIR=build/python /usr/bin/python3 tests/fuzz/make_seeds.py
"""
import math
import os
import shutil

import numpy as np

from drapelab import measure

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORPUS = os.path.join(ROOT, "tests", "fuzz", "corpus")
SILHOUETTE = os.path.join(ROOT, "assets", "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")

# (file name suffix, pixel type, channels): every layout write_image makes, in each supported format.
LAYOUTS = [("grey8.png", "uint8", 1), ("rgba16.png", "uint16", 4), ("rgb8.jpg", "uint8", 3),
           ("grey16.tif", "uint16", 1), ("rgbf.tif", "float", 3), ("greyf.exr", "float", 1),
           ("rgbaf.exr", "float", 4), ("rgb8.bmp", "uint8", 3)]


def fresh(target):
    folder = os.path.join(CORPUS, target)
    shutil.rmtree(folder, ignore_errors=True)
    os.makedirs(folder)
    return folder


def image_seeds():
    folder = fresh("image")
    shutil.copy(SILHOUETTE, os.path.join(folder, "cusick_fabric02.jpg"))
    lum, _ = measure.read_image(SILHOUETTE)
    mask = (lum > 0.5).astype(float)  # a clean two-tone silhouette compresses to a few KB
    small = mask.reshape(64, 4, 64, 4).mean(axis=(1, 3))
    tiny = np.add.outer(np.arange(8), np.arange(8)) / 14.0
    for name, image, layouts in (("sil256", mask, [LAYOUTS[0], LAYOUTS[5]]), ("sil64", small, LAYOUTS),
                                 ("tiny8", tiny, LAYOUTS)):
        for suffix, pixel_type, channels in layouts:
            measure.write_image(os.path.join(folder, f"{name}_{suffix}"), image, pixel_type, channels)


def disk_obj(spelling):
    """A hexagon fan of radius 0.15 m around a centre vertex (inside the 0.09 m support disk)."""
    lines = ["# tiny Cusick disk", "v 0 0 0"]
    lines += [f"v {0.15 * math.cos(k * math.pi / 3):.6g} {0.15 * math.sin(k * math.pi / 3):.6g} 0" for k in range(6)]
    if spelling == "vt":
        lines += ["vt 0.5 0.5"] + [f"vt {0.5 + 0.5 * math.cos(k * math.pi / 3):.4f} "
                                    f"{0.5 + 0.5 * math.sin(k * math.pi / 3):.4f}" for k in range(6)]
    for k in range(6):
        a, b = 2 + k, 2 + (k + 1) % 6
        face = {"plain": f"f 1 {a} {b}", "vt": f"f 1/1 {a}/{a} {b}/{b}", "normals": f"f 1//1 {a}//1 {b}//1",
                "negative": f"f -7 {a - 8} {b - 8}"}[spelling]
        lines.append(face)
    if spelling == "normals":
        lines.insert(1, "vn 0 0 1")
    return "\n".join(lines) + "\n"


def obj_seeds():
    folder = fresh("obj")
    for spelling in ("plain", "vt", "normals", "negative"):
        with open(os.path.join(folder, f"disk_{spelling}.obj"), "w") as f:
            f.write(disk_obj(spelling))
    with open(os.path.join(folder, "disk_quads.obj"), "w") as f:  # polygons are fan-triangulated
        f.write("v 0 0 0\nv 0.15 0 0\nv 0.15 0.15 0\nv 0 0.15 0\nv -0.15 0.15 0\nv -0.15 0 0\n"
                "f 1 2 3 4\nf 1 4 5 6\n")
    # The coarsest template mesh (circle1) cut to the faces among its first 60 vertices.
    v, f = [], []
    with open(os.path.join(ROOT, "assets", "cusick", "template_meshes", "circle1.obj")) as src:
        for line in src:
            if line.startswith("v "):
                v.append(line)
            elif line.startswith("f ") and all(int(t.split("/")[0]) <= 60 for t in line.split()[1:]):
                f.append(line)
    with open(os.path.join(folder, "circle1_part.obj"), "w") as out:
        out.writelines(v[:60] + f)


def manifest_seeds():
    folder = fresh("manifest")
    bundled = os.path.join(ROOT, "assets", "cusick", "manifest.csv")
    shutil.copy(bundled, os.path.join(folder, "bundled.csv"))
    text = open(bundled).read()
    variants = {
        "bom_crlf.csv": "\ufeff" + text.replace("\n", "\r\n"),
        "quoted.csv": 'silhouette,fabric,sample,capture,name\n"a, b.png",7,1,2,"Linen, ""washed"""\n',
        "minimal.csv": "fabric,sample,capture,silhouette\n1,1,1,a.png\n\n2,-3,+4,/abs/b.jpg\n",
        "numbers.csv": "fabric,sample,capture,silhouette,density_kg_m2,thickness_mm\n"
                       "1,1,1,a.png,1e-3,\n1,1,2,b.png,,0.5\n",
    }
    for name, content in variants.items():
        with open(os.path.join(folder, name), "w", encoding="utf-8", newline="") as f:
            f.write(content)


if __name__ == "__main__":
    image_seeds()
    obj_seeds()
    manifest_seeds()
    for target in sorted(os.listdir(CORPUS)):
        files = os.listdir(os.path.join(CORPUS, target))
        size = sum(os.path.getsize(os.path.join(CORPUS, target, n)) for n in files)
        print(f"{target}: {len(files)} seeds, {size} bytes")
