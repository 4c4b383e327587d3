// manifest.csv loader.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "measure/manifest.hpp"
#include "measure_test_support.hpp"

using namespace drapelab;
using namespace drapelab::measure_testing;

TEST(MeasureManifest, ReadsTheBundledManifestAndResolvesPaths) {
  const auto rows = read_manifest(asset("cusick/manifest.csv"), true);
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[0].fabric, 2);
  EXPECT_EQ(rows[0].name, "Cotton Blue");
  EXPECT_EQ(rows[0].weave, "Basket");
  EXPECT_DOUBLE_EQ(rows[0].density_kg_m2, 0.192);
  EXPECT_DOUBLE_EQ(rows[0].thickness_mm, 0.402);
  EXPECT_EQ(rows[0].sample, 2);
  EXPECT_EQ(rows[0].capture, 1);
  EXPECT_TRUE(std::filesystem::exists(rows[0].silhouette));
  EXPECT_TRUE(std::filesystem::exists(rows[0].mesh));
  EXPECT_TRUE(rows[1].mesh.empty());
  EXPECT_EQ(rows[1].material, "Viscose 95% Elastane 5%");
}

TEST(MeasureManifest, QuotedFieldsAndMissingOptionalColumns) {
  TempDir dir;
  std::ofstream(dir.file("m.csv")) << "silhouette,fabric,sample,capture,name\n"
                                      "a.png,7,1,2,\"Linen, \"\"washed\"\"\"\n";
  const auto rows = read_manifest(dir.file("m.csv"));
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].name, "Linen, \"washed\"");
  EXPECT_EQ(rows[0].silhouette, dir.file("a.png"));
  EXPECT_TRUE(std::isnan(rows[0].density_kg_m2));
}

TEST(MeasureManifest, ProblemsNameTheFileAndLine) {
  TempDir dir;
  expect_input_error([&] { read_manifest(dir.file("none.csv")); }, {"none.csv", "cannot open"});
  std::ofstream(dir.file("empty.csv")).close();
  expect_input_error([&] { read_manifest(dir.file("empty.csv")); }, {"empty.csv", "empty"});
  std::ofstream(dir.file("cols.csv")) << "fabric,sample,silhouette\n1,1,a.png\n";
  expect_input_error([&] { read_manifest(dir.file("cols.csv")); }, {"cols.csv", "'capture'"});
  std::ofstream(dir.file("bad.csv")) << "fabric,sample,capture,silhouette\n1,1,1,a.png\nx,1,1,b.png\n";
  expect_input_error([&] { read_manifest(dir.file("bad.csv")); }, {"bad.csv:3", "'fabric'", "'x'"});
  std::ofstream(dir.file("gone.csv")) << "fabric,sample,capture,silhouette\n1,1,1,missing.png\n";
  EXPECT_NO_THROW(read_manifest(dir.file("gone.csv")));
  expect_input_error([&] { read_manifest(dir.file("gone.csv"), true); }, {"gone.csv:2", "missing.png", "not found"});
}
