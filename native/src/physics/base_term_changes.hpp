// Changes an effect makes inside a base term, for effects that are not an added energy but a change of the base
// physics itself (the rest shape of the membrane, a spatial field over the bending stiffness). An effect fills
// them from its spec's `change_base_terms` (physics/effect.hpp); the model hands them to the stretch and bend
// terms it builds. Both are written so that the base term is unchanged bit for bit when no effect asks for a
// change (the term takes its original path) and when the effect's parameters are at their off values (the
// change multiplies by exactly 1). Several effects may add to one change: their contributions sum.
//
// The base terms give exact derivatives in the effect parameters too (energy, force, step matrix), checked by
// tests/native/physics/test_effect_parameters.cpp for every registered effect.
#pragma once
#include <cmath>
#include <vector>

#include <Eigen/Core>

namespace drapelab {

// Stretching: the rest pattern is scaled along its axes, u -> (1 - s_u) u (weft), v -> (1 - s_v) v (warp),
// so rest lengths shrink by the strains s_u, s_v [1] (positive: the fabric shrank; the flat specimen is then
// under tension). The strains are linear in parameters: s_u = sum_k weft[k] p[indices[k]], s_v likewise.
struct RestScaling {
  std::vector<int> indices;
  std::vector<double> weft, warp;

  bool active() const { return !indices.empty(); }
  void add(int index, double weft_coefficient, double warp_coefficient) {
    indices.push_back(index);
    weft.push_back(weft_coefficient);
    warp.push_back(warp_coefficient);
  }
  // (s_u, s_v) at p.
  void strains(const Eigen::VectorXd& p, double& su, double& sv) const {
    su = 0;
    sv = 0;
    for (size_t k = 0; k < indices.size(); ++k) {
      su += weft[k] * p[indices[k]];
      sv += warp[k] * p[indices[k]];
    }
  }
};

// A per-element energy multiplier m_e = exp(sum_k c_ek p[indices[k]]) (a log-linear field; m = 1 at p = 0).
struct EnergyModulation {
  std::vector<int> indices;
  std::vector<std::vector<double>> coefficients;  // [k][e]: mode k's coefficient on element e

  bool active() const { return !indices.empty(); }
  void add(int index, std::vector<double> per_element) {
    indices.push_back(index);
    coefficients.push_back(std::move(per_element));
  }
  double log_multiplier(int e, const Eigen::VectorXd& p) const {
    double s = 0;
    for (size_t k = 0; k < indices.size(); ++k) s += coefficients[k][e] * p[indices[k]];
    return s;
  }
};

// Bending's rest dihedral angles (a plastic set): theta_rest,e = sum_k c_ek p[indices[k]] [rad], linear in the
// parameters (0 at p = 0: the flat rest shape). The bend term's angle change becomes d = theta - theta_rest(p).
struct RestAngles {
  std::vector<int> indices;
  std::vector<std::vector<double>> coefficients;  // [k][e]: rad per unit of parameter k on bending edge e

  bool active() const { return !indices.empty(); }
  void add(int index, std::vector<double> per_element) {
    indices.push_back(index);
    coefficients.push_back(std::move(per_element));
  }
  double angle(int e, const Eigen::VectorXd& p) const {
    double s = 0;
    for (size_t k = 0; k < indices.size(); ++k) s += coefficients[k][e] * p[indices[k]];
    return s;
  }
};

// Bending beyond the table's curvature range: each edge's energy is multiplied by M = exp(q s(alpha)), with q the
// sum of p[indices[k]] (a log factor) and s a C1 ramp (smoothstep) in ln(alpha) of the edge's curvature measure
// alpha [1/m] from 0 at `start` to 1 at `full` (the bend term's alpha, physics/bend.hpp). M = 1 exactly at q = 0
// and below `start`: the table's own range is untouched. A falling M can make the energy concave in the angle (the
// moment falling as the fold sharpens: a snap); how far q may go below 0 with E'' > 0 grows with the ramp's length
// in log curvature (10 -> 80 /m: to about -0.95; 10 -> 40 /m: only to -0.5), the effect's bound says where.
struct CurvatureFactor {
  std::vector<int> indices;
  double start = 0, full = 0;

  bool active() const { return !indices.empty(); }
  double log_factor(const Eigen::VectorXd& p) const {
    double q = 0;
    for (int i : indices) q += p[i];
    return q;
  }
};

struct BaseTermChanges {
  RestScaling stretch_rest;
  EnergyModulation bend;
  RestAngles bend_rest;  // rest_curvature
  CurvatureFactor bend_curvature;  // high_curvature_bending
  // The handle holds the vertices whose rest radius is below this [m] instead of the model's support radius
  // (disk_contact: a small centre clamp; the rest of the specimen lies on the support disk). NaN: unchanged.
  double handle_radius = std::nan("");
  // The effect builds the support's hold itself (offset: a smooth hold of the disk shifted under the specimen),
  // so the model adds no HandleTerm. handle_vertices() stays the base set.
  bool handle_replaced = false;
};

}  // namespace drapelab
