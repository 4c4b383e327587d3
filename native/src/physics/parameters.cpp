#include "physics/parameters.hpp"

#include "util/error.hpp"

namespace drapelab {

int ParameterLayout::add(const std::string& name, const std::string& unit, int entries_per_element,
                         int num_elements, bool shared) {
  if (has(name)) throw InputError("parameter block '" + name + "' defined twice");
  ParameterBlock b;
  b.name = name;
  b.unit = unit;
  b.offset = size_;
  b.entries_per_element = entries_per_element;
  b.shared = shared;
  b.size = entries_per_element * (shared ? 1 : num_elements);
  blocks_.push_back(b);
  size_ += b.size;
  return b.offset;
}

const ParameterBlock& ParameterLayout::block(const std::string& name) const {
  for (const auto& b : blocks_)
    if (b.name == name) return b;
  throw InputError("no parameter block named '" + name + "'");
}

bool ParameterLayout::has(const std::string& name) const {
  for (const auto& b : blocks_)
    if (b.name == name) return true;
  return false;
}

}  // namespace drapelab
