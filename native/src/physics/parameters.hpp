// The flat parameter vector of a model and its named blocks.
//
// Every physical parameter lives in one named block with a unit: "stretch" (N/m, 24 per face or one
// shared table), "bend" (N m, 15 per bending edge or one shared table), "density" (kg/m^2),
// "handle_stiffness" (N/m), and, later, one block per optional effect. Gradients use the same layout.
#pragma once
#include <Eigen/Core>
#include <string>
#include <vector>

namespace drapelab {

struct ParameterBlock {
  std::string name;
  std::string unit;
  int offset = 0;
  int size = 0;
  int entries_per_element = 0;  // table size (24 stretch, 15 bend, 1 scalar)
  bool shared = true;           // one table for all elements (homogeneous) or one per element
};

class ParameterLayout {
 public:
  // Adds a block; returns its offset.
  int add(const std::string& name, const std::string& unit, int entries_per_element, int num_elements, bool shared);
  const ParameterBlock& block(const std::string& name) const;
  bool has(const std::string& name) const;
  const std::vector<ParameterBlock>& blocks() const { return blocks_; }
  int size() const { return size_; }

 private:
  std::vector<ParameterBlock> blocks_;
  int size_ = 0;
};

}  // namespace drapelab
