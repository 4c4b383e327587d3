// Geometry: Cusick specimen generator, OBJ round trip, bending topology.
#include <gtest/gtest.h>

#include <cstdio>

#include "../test_support.hpp"
#include "geometry/obj.hpp"
#include "util/error.hpp"

using namespace drapelab;

TEST(CusickSpecimen, GeneratedAtTheTemplateVertexCounts) {
  for (int level = 1; level <= 5; ++level) {
    const TriangleMesh m = make_cusick_specimen(cusick_template_vertices(level));
    EXPECT_EQ(m.num_vertices(), cusick_template_vertices(level));
    validate_mesh(m);
    // A disk: Euler characteristic 1, radius 15 cm, all faces counter-clockwise.
    const auto edges = bending_edges(m);
    const int boundary = 3 * m.num_faces() - 2 * static_cast<int>(edges.size());
    const int num_edges = static_cast<int>(edges.size()) + boundary;
    EXPECT_EQ(m.num_vertices() - num_edges + m.num_faces(), 1);
    EXPECT_NEAR(m.positions.rowwise().norm().maxCoeff(), 0.15, 1e-12);
    EXPECT_GT(rest_areas(m).minCoeff(), 0.0);
    EXPECT_NEAR(rest_areas(m).sum(), M_PI * 0.15 * 0.15, 0.02 * M_PI * 0.15 * 0.15);
  }
}

TEST(Obj, RoundTripAndErrors) {
  const TriangleMesh m = make_cusick_specimen(50);
  const std::string path = ::testing::TempDir() + "/drapelab_roundtrip.obj";
  write_obj(path, m.positions, m.faces);
  const TriangleMesh r = read_obj(path);
  EXPECT_EQ(r.num_vertices(), m.num_vertices());
  EXPECT_EQ(r.faces, m.faces);
  EXPECT_LT((r.positions - m.positions).cwiseAbs().maxCoeff(), 1e-11);
  EXPECT_THROW(read_obj(::testing::TempDir() + "/missing.obj"), InputError);
  const std::string empty = ::testing::TempDir() + "/drapelab_empty.obj";
  std::fclose(std::fopen(empty.c_str(), "w"));
  try {
    read_obj(empty);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("drapelab_empty.obj"), std::string::npos);
  }
  EXPECT_THROW(write_obj("/nonexistent-dir/x.obj", m.positions, m.faces), InputError);
}

TEST(Obj, LoadsTheBundledTemplates) {
  for (int level = 1; level <= 5; ++level) {
    const TriangleMesh m = load_cusick_template(level, drapelab::testing::template_dir());
    EXPECT_EQ(m.num_vertices(), cusick_template_vertices(level));
    validate_mesh(m);
  }
}

TEST(CusickSpecimen, MissingTemplateIsAnErrorNamingThePath) {
  try {
    load_cusick_template(1, ::testing::TempDir() + "/no_templates_here");
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("no_templates_here/circle1.obj"), std::string::npos) << e.what();
  }
}
