#include "physics/model.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <algorithm>

#include "physics/bend.hpp"
#include "physics/gravity.hpp"
#include "physics/handle.hpp"
#include "physics/seam.hpp"
#include "physics/stretch.hpp"
#include "util/error.hpp"

namespace drapelab {

StretchTable cotton_blue_stretch_table() {
  StretchTable t;
  const double c11[6] = {150.0862, 189.2275, 51.2988, 36.7329, 58.9375, 207.3079};
  const double c12[6] = {0.3456, 2.3716, 4.9362, 6.3891, 5.1495, 2.2163};
  const double c22[6] = {150.4856, 200.7334, 60.3071, 32.7261, 49.8735, 193.4768};
  const double c33[6] = {10.189, 20.905, 25.393, 30.462, 25.055, 20.669};
  for (int r = 0; r < 6; ++r) t.row(r) << c11[r], c12[r], c22[r], c33[r];
  return t;
}

BendTable cotton_blue_bend_table() {
  BendTable t;
  t << 1.071e-5, 2.914e-5, 9.287e-5, 9.498e-5, 8.145e-5,  //
      2.753e-5, 4.838e-5, 3.838e-5, 7.398e-5, 6.982e-5,   //
      2.460e-5, 1.028e-4, 1.234e-4, 1.002e-4, 1.022e-4;
  return t;
}

Model::Model(const TriangleMesh& mesh, const ModelOptions& options) : mesh_(mesh), options_(options) {
  validate_mesh(mesh_);
  orient_faces_ccw(mesh_);
  if (!(options.gravity >= 0) || !std::isfinite(options.gravity)) throw InputError("model: gravity must be >= 0");
  if (!(options.support_radius > 0)) throw InputError("model: support radius must be > 0");
  edges_ = drapelab::bending_edges(mesh_);
  const int nf = mesh_.num_faces(), ne = static_cast<int>(edges_.size()), nv = mesh_.num_vertices();
  const bool shared = !options.heterogeneous;
  const int stretch_off = layout_.add("stretch", "N/m", 24, nf, shared);
  const int bend_off = layout_.add("bend", "N m", 15, ne, shared);
  const int density_off = layout_.add("density", "kg/m^2", 1, 1, true);
  const int handle_off = layout_.add("handle_stiffness", "N/m", 1, 1, true);
  for (const auto& [name, values] : options.effects) {
    const EffectSpec& spec = find_effect(name);  // unknown names are an error naming the registered ones
    for (const auto& [param, value] : values) check_effect_value(spec, param, value);
  }
  for (const EffectSpec& spec : effect_registry()) {
    if (!options.effects.count(spec.name)) continue;
    active_effects_.push_back(spec.name);
    for (const auto& q : spec.parameters) layout_.add(effect_block_name(spec.name, q.name), q.unit, 1, 1, true);
  }

  const Eigen::VectorXd areas = rest_areas(mesh_);
  area_weights_.setZero(nv);
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) area_weights_[mesh_.faces(f, k)] += std::abs(areas[f]) / 3.0;

  std::vector<Eigen::Vector3d> anchors;
  if (!options.held_vertices.empty()) {
    std::vector<char> seen(nv, 0);
    for (int i : options.held_vertices) {
      if (i < 0 || i >= nv) throw InputError("model: held vertex " + std::to_string(i) + " is not a vertex index");
      if (seen[i]++) throw InputError("model: held vertex " + std::to_string(i) + " is listed twice");
      handle_vertices_.push_back(i);
      anchors.push_back(mesh_.positions.row(i).transpose());
    }
  } else {
    for (int i = 0; i < nv; ++i)
      if (mesh_.uv.row(i).norm() < options.support_radius) {
        handle_vertices_.push_back(i);
        anchors.push_back(mesh_.positions.row(i).transpose());
      }
  }
  if (handle_vertices_.empty()) throw InputError("model: no vertex lies on the support disk (rest radius < support radius)");
  for (const auto& s : options.seams) {
    if (s[0] < 0 || s[0] >= nv || s[1] < 0 || s[1] >= nv || s[0] == s[1])
      throw InputError("model: seam (" + std::to_string(s[0]) + ", " + std::to_string(s[1]) +
                       ") does not pair two distinct vertices");
  }
  if (!options.seams.empty() && !(options.seam_stiffness > 0 && std::isfinite(options.seam_stiffness)))
    throw InputError("model: seam stiffness must be > 0 N/m");

  const EffectContext context{mesh_, edges_, area_weights_, handle_vertices_, layout_, options_};
  BaseTermChanges changes;  // what active effects change inside the base terms (none: the base model)
  for (const std::string& name : active_effects_) {
    const EffectSpec& spec = find_effect(name);
    if (spec.change_base_terms) spec.change_base_terms(context, changes);
  }
  if (!std::isnan(changes.handle_radius)) {  // a smaller clamp (disk_contact): the effects' terms see the new set
    handle_vertices_.clear();
    anchors.clear();
    for (int i = 0; i < nv; ++i)
      if (mesh_.uv.row(i).norm() < changes.handle_radius) {
        handle_vertices_.push_back(i);
        anchors.push_back(mesh_.positions.row(i).transpose());
      }
    if (handle_vertices_.empty())
      throw InputError("model: no vertex lies inside the clamp (rest radius < clamp radius); use a larger clamp");
  }
  terms_.push_back(std::make_unique<StretchTerm>(mesh_, stretch_off, shared, changes.stretch_rest));
  terms_.push_back(std::make_unique<BendTerm>(mesh_, edges_, bend_off, shared, changes.bend, changes.bend_rest,
                                                changes.bend_curvature));
  terms_.push_back(std::make_unique<GravityTerm>(area_weights_, density_off, options.gravity));
  if (!changes.handle_replaced) {
    auto handle = std::make_unique<HandleTerm>(handle_vertices_, anchors, handle_off);
    handle_ = handle.get();
    terms_.push_back(std::move(handle));
  }
  if (!options.seams.empty()) terms_.push_back(std::make_unique<SeamTerm>(options.seams, options.seam_stiffness));
  for (const std::string& name : active_effects_) {
    const EffectSpec& spec = find_effect(name);
    if (spec.make_terms)
      for (auto& t : spec.make_terms(context)) terms_.push_back(std::move(t));
    if (spec.make_observation) observations_.push_back(spec.make_observation(context));
  }

  std::vector<std::vector<int>> stencils;
  for (const auto& t : terms_) {
    auto s = t->stencils();
    stencils.insert(stencils.end(), s.begin(), s.end());
  }
  pattern_ = SparsePattern(nv, stencils);
  for (const auto& t : terms_) t->bind_pattern(pattern_);

  defaults_.setZero(layout_.size());
  fill_stretch(defaults_, cotton_blue_stretch_table());
  fill_bend(defaults_, cotton_blue_bend_table());
  defaults_[density_off] = options.density;
  defaults_[handle_off] = options.handle_stiffness;
  for (const std::string& name : active_effects_) {
    const auto& given = options.effects.at(name);
    for (const auto& q : find_effect(name).parameters) {
      const auto it = given.find(q.name);
      defaults_[layout_.block(effect_block_name(name, q.name)).offset] = it == given.end() ? q.off : it->second;
    }
  }
  validate_parameters(defaults_);
}

Eigen::VectorXd Model::observe(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const {
  if (x.size() != num_dofs())
    throw InputError("observe: expected " + std::to_string(num_dofs()) + " position values, got " +
                     std::to_string(x.size()));
  Eigen::VectorXd y = x, next(x.size());
  for (const auto& t : observations_) {
    t->apply(y, p, next);
    y.swap(next);
  }
  return y;
}

void Model::add_observe_vjp(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& gy,
                            Eigen::VectorXd& gx, Eigen::VectorXd& gp) const {
  if (x.size() != num_dofs() || gy.size() != num_dofs() || gx.size() != num_dofs() || gp.size() != layout_.size())
    throw InputError("observe: position, gradient or parameter vector of the wrong size");
  if (observations_.empty()) {
    gx += gy;
    return;
  }
  // The inputs of each transform (forward again), then the chain backwards.
  std::vector<Eigen::VectorXd> inputs{x};
  for (size_t k = 0; k + 1 < observations_.size(); ++k) {
    Eigen::VectorXd next(x.size());
    observations_[k]->apply(inputs.back(), p, next);
    inputs.push_back(std::move(next));
  }
  Eigen::VectorXd g = gy;
  for (size_t k = observations_.size(); k-- > 0;) {
    Eigen::VectorXd gin = Eigen::VectorXd::Zero(x.size());
    observations_[k]->add_vjp(inputs[k], p, g, gin, gp);
    g.swap(gin);
  }
  gx += g;
}

void Model::set_handle_anchors(const MatrixX3d& anchors) {
  if (handle_ == nullptr) throw InputError("handle anchors: an effect (offset) replaces the handle; it has no anchors");
  if (anchors.rows() != static_cast<Eigen::Index>(handle_vertices_.size()))
    throw InputError("handle anchors: expected " + std::to_string(handle_vertices_.size()) + " rows, got " +
                     std::to_string(anchors.rows()));
  if (!anchors.allFinite()) throw InputError("handle anchors: not finite");
  std::vector<Eigen::Vector3d> a(handle_vertices_.size());
  for (size_t k = 0; k < a.size(); ++k) a[k] = anchors.row(static_cast<Eigen::Index>(k)).transpose();
  handle_->set_anchors(a);
}

Eigen::VectorXd Model::rest_positions() const {
  Eigen::VectorXd x(num_dofs());
  for (int i = 0; i < num_vertices(); ++i) x.segment<3>(3 * i) = mesh_.positions.row(i).transpose();
  return x;
}

Eigen::VectorXd Model::masses(const Eigen::VectorXd& p) const {
  return p[layout_.block("density").offset] * area_weights_;
}

void Model::fill_stretch(Eigen::VectorXd& p, const StretchTable& table) const {
  const auto& b = layout_.block("stretch");
  for (int o = b.offset; o < b.offset + b.size; o += 24)
    for (int k = 0; k < 24; ++k) p[o + k] = table.data()[k];
}

void Model::fill_bend(Eigen::VectorXd& p, const BendTable& table) const {
  const auto& b = layout_.block("bend");
  for (int o = b.offset; o < b.offset + b.size; o += 15)
    for (int k = 0; k < 15; ++k) p[o + k] = table.data()[k];
}

void Model::validate_parameters(const Eigen::VectorXd& p) const {
  if (p.size() != layout_.size()) {
    std::ostringstream s;
    s << "parameters: expected " << layout_.size() << " values, got " << p.size();
    throw InputError(s.str());
  }
  static const char* stretch_names[4] = {"c11", "c12", "c22", "c33"};
  for (const auto& b : layout_.blocks()) {
    const size_t dot = b.name.find('.');
    if (dot != std::string::npos) {  // an effect's parameter: its registry bounds
      try {
        check_effect_value(find_effect(b.name.substr(0, dot)), b.name.substr(dot + 1), p[b.offset]);
      } catch (const InputError& e) {
        throw InputError(std::string("parameters: ") + e.what());
      }
      const std::string effect = b.name.substr(0, dot), param = b.name.substr(dot + 1);
      for (const auto& q : find_effect(effect).parameters)
        if (q.name == param && q.structural && p[b.offset] != defaults_[b.offset]) {
          std::ostringstream s;
          s << "parameters: " << b.name << " = " << p[b.offset] << " differs from the model's " << defaults_[b.offset]
            << ": it is structural (it chooses the model's structure: which vertices it holds, whether a contact "
            << "term exists); build the model with the value";
          throw InputError(s.str());
        }
      continue;
    }
    for (int k = 0; k < b.size; ++k) {
      const double v = p[b.offset + k];
      const int element = k / b.entries_per_element, entry = k % b.entries_per_element;
      const bool may_be_negative = b.name == "stretch" && entry % 4 == 1;  // Poisson coupling c12
      const bool finite = std::isfinite(v), negative = !may_be_negative && v < 0;
      const bool density_not_positive = b.name == "density" && !(v > 0);
      if (finite && !negative && !density_not_positive) continue;
      // The message is built only for a bad entry (garments validate ~10^5 table entries every step).
      std::ostringstream where;
      where << "parameters: block '" << b.name << "'";
      if (!b.shared) where << " element " << element;
      if (b.name == "stretch") where << " row " << entry / 4 << " " << stretch_names[entry % 4];
      if (b.name == "bend") where << " row " << entry / 5 << " column " << entry % 5;
      if (!finite) throw InputError(where.str() + " is not finite (" + std::to_string(v) + ")");
      if (negative) throw InputError(where.str() + " is negative (" + std::to_string(v) + " " + b.unit + ")");
      throw InputError(where.str() + " must be > 0 (got " + std::to_string(v) + " kg/m^2)");
    }
  }
}

double Model::energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const {
  double E = 0;
  for (const auto& t : terms_) E += t->energy(x, p);
  return E;
}

void Model::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const {
  for (const auto& t : terms_) t->add_gradient(x, p, g);
}

void Model::add_term_impl(std::unique_ptr<Term> term) {
  if (!term) throw InputError("model: add_term needs a term");
  for (const auto& stencil : term->stencils())
    for (int a : stencil)
      for (int b : stencil)
        try {
          if (a < 0 || a >= num_vertices() || b < 0 || b >= num_vertices()) throw std::logic_error("index");
          pattern_.index(3 * std::min(a, b), 3 * std::max(a, b));
        } catch (const std::logic_error&) {
          throw InputError("model: term '" + term->name() + "' couples vertices outside the model's pattern");
        }
  term->bind_pattern(pattern_);
  terms_.push_back(std::move(term));
}

}  // namespace drapelab
