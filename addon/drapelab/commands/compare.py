"""`drapelab compare --mesh OBJ --image IMG [--camera ortho|perspective] --json OUT.json [--overlay PNG]`.

Compares a 3D drape (OBJ, metres, support disk centred at the origin, z up) with a measured silhouette:
iou and mse of the model silhouette (rendered with the camera) against the measured one; the drape
coefficient and node count of each (the mesh's from its orthographic top-down shadow); r_theta_rmse_m,
the radius-angle curves' RMSE after the best rotation. --overlay writes a PNG showing measured-only,
model-only and shared pixels in three colours with a legend.
"""
import os

from .measure import add_calibration_arguments, calibration_from_args


def register(subparsers):
    p = subparsers.add_parser("compare", help="compare a 3D drape mesh with a measured silhouette",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--mesh", required=True, metavar="OBJ", help="3D drape mesh (Wavefront OBJ, metres)")
    p.add_argument("--image", required=True, metavar="IMG", help="measured top-down silhouette or photo")
    p.add_argument("--camera", choices=["ortho", "perspective"], default="ortho",
                   help="measurement model for iou/mse: calibrated orthographic (default) or the paper's "
                        "perspective camera (fov 0.5 rad, eye 0.7 m)")
    add_calibration_arguments(p)
    p.add_argument("--threshold", type=float, default=None, help="silhouette threshold (default automatic)")
    p.add_argument("--json", metavar="OUT.json", default=None, help="write the metrics here")
    p.add_argument("--overlay", metavar="PNG", default=None, help="write an overlay image here")
    p.set_defaults(func=run)


def run(args):
    from .. import measure

    for path, what in ((args.json, "JSON"), (args.overlay, "overlay")):
        if path:
            measure.check_output_path(path, what)
    cal = calibration_from_args(args)
    metrics, measured, model = measure.compare_mesh_image(args.mesh, args.image, camera=args.camera,
                                                          calibration=cal, threshold=args.threshold)
    result = {"mesh": args.mesh, "image": args.image, **metrics}
    print(f"IoU {metrics['iou']:.3f}, MSE {metrics['mse']:.4f}, drape coefficient "
          f"{metrics['drape_coefficient_mesh']:.3f} (mesh) / {metrics['drape_coefficient_image']:.3f} (image), "
          f"nodes {metrics['node_count_mesh']} / {metrics['node_count_image']}, "
          f"r(theta) RMSE {1000 * metrics['r_theta_rmse_m']:.1f} mm")
    if args.json:
        measure.write_json(args.json, result)
        print(f"wrote {args.json}")
    if args.overlay:
        notes = [f"camera  {args.camera}",
                 f"IoU     {metrics['iou']:.3f}",
                 f"MSE     {metrics['mse']:.4f}",
                 f"DC      {metrics['drape_coefficient_image']:.3f} measured",
                 f"        {metrics['drape_coefficient_mesh']:.3f} model",
                 f"nodes   {metrics['node_count_image']} measured, {metrics['node_count_mesh']} model",
                 f"r(theta) RMSE {1000 * metrics['r_theta_rmse_m']:.1f} mm"]
        ortho = measure.calibration(metrics["px_per_m"], metrics["centre_px"]) if args.camera == "ortho" else None
        measure.write_overlay(args.overlay, measured, model, title=f"measured {os.path.basename(args.image)}\nmodel {os.path.basename(args.mesh)}", notes=notes,
                              calibration=ortho)
        print(f"wrote {args.overlay}")
    return 0
