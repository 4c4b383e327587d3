"""Figures of the garment assets for docs/garments.md: the skirts' uv patterns and their 3D rest placement on the
body (docs/img/garment_skirts.png), and the body's motions (docs/img/garment_motions.png).

    PYTHONPATH=addon:build/python /usr/bin/python3 tools/garment_figure.py [OUT_DIR]
"""
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from drapelab.garment import body as gbody, skirt as gskirt  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def boundary_edges(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u[c == 1]


def pieces(g):
    """Vertex indices of each uv island (pattern piece)."""
    label = np.arange(g.num_vertices)
    for _ in range(g.num_vertices):
        merged = np.minimum.reduce([label[g.faces[:, 0]], label[g.faces[:, 1]], label[g.faces[:, 2]]])
        new = label.copy()
        for k in range(3):
            np.minimum.at(new, g.faces[:, k], merged)
        if np.array_equal(new, label):
            break
        label = new
    return [np.flatnonzero(label == v) for v in np.unique(label)]


def pattern_panel(ax, g, title):
    ax.triplot(g.uv[:, 0], g.uv[:, 1], g.faces, lw=0.15, color="0.6")
    wb = np.zeros(g.num_vertices, bool)
    wb[g.waist_vertices] = True
    band = wb[g.faces].all(axis=1)
    ax.tripcolor(g.uv[:, 0], g.uv[:, 1], g.faces[band], facecolors=np.ones(band.sum()), cmap="Oranges", vmin=0,
                 vmax=2, alpha=0.8)
    seam = np.isin(boundary_edges(g.faces), g.seams).all(axis=1)
    ax.add_collection(LineCollection(g.uv[boundary_edges(g.faces)[seam]], colors="tab:red", lw=1.6))
    # grain line: the centre line of each piece (uv island), along +v
    for piece in pieces(g):
        uv = g.uv[piece]
        cu = 0.5 * (uv[:, 0].min() + uv[:, 0].max())
        r = np.hypot(uv[:, 0] - cu, uv[:, 1])
        ax.annotate("", xy=(cu, r.max() * 0.95), xytext=(cu, r.min() + 0.03),
                    arrowprops=dict(arrowstyle="->", color="tab:blue", lw=1.5))
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("u = weft (m)", fontsize=8)
    ax.set_ylabel("v = warp (m)", fontsize=8)
    ax.tick_params(labelsize=7)


def shaded(ax, positions, faces, colour, alpha=1.0, light=(0.3, -0.8, 0.5)):
    p = positions[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-300
    shade = 0.35 + 0.65 * np.abs(n @ (np.array(light) / np.linalg.norm(light)))
    rgb = np.clip(np.array(matplotlib.colors.to_rgb(colour))[None] * shade[:, None], 0, 1)
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    coll = Poly3DCollection(p, facecolors=np.c_[rgb, np.full(len(rgb), alpha)], edgecolors="none")
    ax.add_collection3d(coll)


def placement_panel(ax, g, body, title, cut=True):
    """The skirt on the body, the near (front, y < 0) half cut away so the body shows inside."""
    keep_body = body.positions[body.faces].mean(axis=1)[:, 2] > 0.35
    shaded(ax, body.positions, body.faces[keep_body], "0.75")
    faces = g.faces
    if cut:
        centre = g.positions[faces].mean(axis=1)
        faces = faces[centre[:, 0] > -0.02]              # keep the body's left half (x > 0): a cutaway
    shaded(ax, g.positions, faces, "tab:purple", alpha=0.95)
    ax.set_xlim(-0.5, 0.5)
    ax.set_ylim(-0.5, 0.5)
    ax.set_zlim(0.35, 1.2)
    ax.set_box_aspect((1, 1, 0.85))
    ax.view_init(elev=12, azim=-60)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)


def skirts_figure(path):
    body = gbody.make_body()
    fig = plt.figure(figsize=(12, 8))
    fig.suptitle("Skirt patterns (red: seams, orange: waistband, blue: grain line = +v) and their 3D rest placement "
                 "on the body (the skirt's right half cut away)", fontsize=10)
    for k, style in enumerate(gskirt.STYLES):
        g = gskirt.make_skirt(style, vertices=2000, body=body)
        strain = np.abs(gskirt.rest_strain(g)).max()
        ax = fig.add_subplot(2, 3, 1 + k)
        pattern_panel(ax, g, f"{style}: pattern, {g.num_vertices} vertices")
        ax3 = fig.add_subplot(2, 3, 4 + k, projection="3d")
        placement_panel(ax3, g, body, f"{style}: rest placement (max |Green strain| {strain:.2f})")
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def motions_figure(path):
    body = gbody.make_body(resolution=20)
    fig = plt.figure(figsize=(12, 4.6))
    shown = {"walk": [0, 8, 14, 22], "twirl": [0, 12, 18, 24], "jump": [0, 8, 10, 13]}
    colours = ["0.7", "tab:blue", "tab:orange", "tab:green"]
    for k, (motion, frames) in enumerate(shown.items()):
        x = gbody.body_frames(body, motion, max(frames) + 1)
        speed = gbody.max_vertex_speed(gbody.body_frames(body, motion, 96))
        title = f"{motion}: frames {frames[1:]} over the rest pose (grey)\nmax vertex speed {speed:.2f} m/s"
        if motion == "twirl":  # seen from above: the hips' outline and the facing direction per frame
            ax = fig.add_subplot(1, 3, 1 + k)
            band = np.abs(body.positions[:, 2] - 0.85) < 0.05
            T = gbody.pelvis_transforms(motion, max(frames) + 1)
            for frame, colour in zip(frames, colours):
                ax.scatter(x[frame, band, 0], x[frame, band, 1], s=2, color=colour)
                front = T[frame, :3, :3] @ np.array([0.0, -0.25, 0.0])
                ax.annotate("", xy=front[:2], xytext=(0, 0), arrowprops=dict(arrowstyle="->", color=colour, lw=2))
            ax.set_aspect("equal")
            ax.set_xlim(-0.3, 0.3)
            ax.set_ylim(-0.3, 0.3)
            ax.set_xlabel("x (m)", fontsize=8)
            ax.set_ylabel("y (m)", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.set_title(title + " (hips from above, arrows: front)", fontsize=8)
            continue
        ax = fig.add_subplot(1, 3, 1 + k, projection="3d")
        for frame, colour in zip(frames, colours):
            shaded(ax, x[frame], body.faces, colour, alpha=0.45 if frame else 0.25)
        ax.set_xlim(-0.5, 0.5)
        ax.set_ylim(-0.5, 0.5)
        ax.set_zlim(0.0, 1.3)
        ax.set_box_aspect((1, 1, 1.3))
        ax.view_init(elev=5, azim=0)   # from the body's left side
        ax.set_axis_off()
        ax.set_title(title + " (seen from the side)", fontsize=8)
    fig.subplots_adjust(left=0.02, right=0.98, top=0.86, bottom=0.04, wspace=0.05)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(out_dir=os.path.join(ROOT, "docs", "img")):
    os.makedirs(out_dir, exist_ok=True)
    skirts_figure(os.path.join(out_dir, "garment_skirts.png"))
    motions_figure(os.path.join(out_dir, "garment_motions.png"))


if __name__ == "__main__":
    main(*sys.argv[1:])
