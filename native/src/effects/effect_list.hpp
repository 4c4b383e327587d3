// The registered effects, one line each (the registration line of docs/adding-an-effect.md). Order is the
// order of their parameter blocks in a model's layout and of `drapelab effects`.
DRAPELAB_EFFECT(tilt)
DRAPELAB_EFFECT(density_variation)
DRAPELAB_EFFECT(prestrain)
DRAPELAB_EFFECT(heterogeneity_map)
DRAPELAB_EFFECT(bending_anisotropy)  // a bend change like heterogeneity_map: over edge directions, not positions
DRAPELAB_EFFECT(high_curvature_bending)  // a bend change over the edges' curvature: sharp folds
DRAPELAB_EFFECT(disk_contact)
DRAPELAB_EFFECT(self_contact)
DRAPELAB_EFFECT(rest_curvature)
DRAPELAB_EFFECT(damping)
DRAPELAB_EFFECT(offset)  // before camera: observations compose in registry order (tester's frame, then image)
DRAPELAB_EFFECT(orientation)  // the tester's frame turned about its axis: after offset's shift, before the camera
DRAPELAB_EFFECT(camera)
