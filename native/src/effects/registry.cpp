#include <cmath>
#include <sstream>

#include "physics/effect.hpp"
#include "util/error.hpp"

namespace drapelab {

#define DRAPELAB_EFFECT(name) EffectSpec make_##name##_effect();
#include "effects/effect_list.hpp"
#undef DRAPELAB_EFFECT

const std::vector<EffectSpec>& effect_registry() {
  static const std::vector<EffectSpec> registry = [] {
    std::vector<EffectSpec> r;
#define DRAPELAB_EFFECT(name) r.push_back(make_##name##_effect());
#include "effects/effect_list.hpp"
#undef DRAPELAB_EFFECT
    return r;
  }();
  return registry;
}

const EffectSpec& find_effect(const std::string& name) {
  for (const auto& e : effect_registry())
    if (e.name == name) return e;
  std::ostringstream s;
  s << "unknown effect '" << name << "' (registered:";
  for (const auto& e : effect_registry()) s << " " << e.name;
  s << ")";
  throw InputError(s.str());
}

std::string effect_block_name(const std::string& effect, const std::string& parameter) {
  return effect + "." + parameter;
}

void check_effect_value(const EffectSpec& spec, const std::string& parameter, double value) {
  for (const auto& q : spec.parameters) {
    if (q.name != parameter) continue;
    if (!std::isfinite(value) || value < q.lower || value > q.upper) {
      std::ostringstream s;
      s << "effect parameter '" << effect_block_name(spec.name, parameter) << "' = " << value << " " << q.unit
        << " is " << (std::isfinite(value) ? "out of range" : "not finite") << " (allowed [" << q.lower << ", "
        << q.upper << "] " << q.unit << ")";
      throw InputError(s.str());
    }
    return;
  }
  std::ostringstream s;
  s << "effect '" << spec.name << "' has no parameter '" << parameter << "' (parameters:";
  for (const auto& q : spec.parameters) s << " " << q.name;
  s << ")";
  throw InputError(s.str());
}

}  // namespace drapelab
