// Self contact in whole Cusick drapes (with disk_contact): the drape stays intersection-free and above the disk;
// its cost against the contact-free and the disk-only drape. The regular test runs circle1 (40 steps); the
// DISABLED_ probe runs circle1 and circle3 for 100 steps with forward and backward timings, the figures of
// docs/lab/self-contact.md (run with --gtest_also_run_disabled_tests --gtest_filter='*SelfContactDrape*').
#include <gtest/gtest.h>

#include <chrono>

#include "../test_support.hpp"
#include "contact/diagnostics.hpp"
#include "contact/distance.hpp"
#include "solver/implicit_euler.hpp"

namespace drapelab {
namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

struct DrapeRun {
  double forward_s = 0, backward_s = 0;
  ContactReport report;
  double disk_clearance = INFINITY;  // of the vertices over the disk (disk_contact.cpp: top 0.5 mm below rest)
  int newton = 0;
};

DrapeRun run(const TriangleMesh& mesh, const EffectValues& effects, int steps, bool backward) {
  ModelOptions o;
  o.effects = effects;
  Model model(mesh, o);
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.steps = steps;
  ro.record = backward;
  DrapeRun r;
  auto t0 = std::chrono::steady_clock::now();
  const Eigen::VectorXd x = sim.forward(model.default_parameters(), ro);
  r.forward_s = seconds_since(t0);
  r.newton = sim.timing().newton_iterations;
  if (backward) {
    t0 = std::chrono::steady_clock::now();
    sim.backward(testing::random_vector(model.num_dofs(), 3));
    r.backward_s = seconds_since(t0);
  }
  r.report = contact_report(mesh.faces, x);
  if (effects.count("disk_contact")) {
    SupportDisk disk;
    disk.radius = o.support_radius;
    disk.rim_radius = 0.002;
    disk.top = -5e-4;
    const double clamp = effects.at("disk_contact").at("clamp_radius_m");
    for (int i = 0; i < model.num_vertices(); ++i) {
      const double rr = mesh.uv.row(i).norm();
      if (rr >= clamp && rr < disk.radius) r.disk_clearance = std::min(r.disk_clearance, support_disk_distance(disk, x.data() + 3 * i));
    }
  }
  return r;
}

void compare(int circle, int steps, bool backward) {
  const TriangleMesh mesh = load_cusick_template(circle, testing::template_dir());
  EffectValues disk, both;
  disk["disk_contact"] = {{"clamp_radius_m", 0.02}, {"friction", 0.3}};
  both = disk;
  both["self_contact"] = {{"thickness_m", 1e-3}};
  const DrapeRun base = run(mesh, {}, steps, backward);
  const DrapeRun d = run(mesh, disk, steps, backward);
  const DrapeRun s = run(mesh, both, steps, backward);
  EXPECT_EQ(s.report.intersecting_pairs, 0);
  EXPECT_GT(s.report.min_distance_m, 0.0);
  EXPECT_GT(s.disk_clearance, 0.0);
  std::printf("circle%d, %d steps, %d vertices\n", circle, steps, mesh.num_vertices());
  for (const auto& [name, r] : {std::pair<const char*, const DrapeRun&>{"no contact", base}, {"disk_contact", d},
                                {"disk + self_contact", s}})
    std::printf("  %-20s forward %7.3f s (%.1f ms/step, x%.2f) backward %7.3f s (x%.2f)  Newton %4d  min distance "
                "%.3g mm  intersecting pairs %d  disk clearance %.3g mm\n",
                name, r.forward_s, 1e3 * r.forward_s / steps, r.forward_s / base.forward_s, r.backward_s,
                backward ? r.backward_s / base.backward_s : 0.0, r.newton, 1e3 * r.report.min_distance_m,
                r.report.intersecting_pairs, 1e3 * r.disk_clearance);
}

TEST(SelfContactDrape, Circle1StaysIntersectionFreeWithDiskContact) { compare(1, 40, false); }

TEST(SelfContactDrape, DISABLED_ProbeCircle1AndCircle3) {
  compare(1, 100, true);
  compare(3, 100, true);
}

}  // namespace
}  // namespace drapelab

namespace drapelab {
namespace {

// Probe: the self-contact term's cost per call at a circle1 drape (energy: broad phase + active set; max_step:
// swept broad phase + ACCD over the candidates; begin_step: the intersection check).
TEST(SelfContactDrape, DISABLED_ProbeTermCostPerCall) {
  const TriangleMesh mesh = load_cusick_template(1, testing::template_dir());
  ModelOptions o;
  o.effects["self_contact"] = {{"thickness_m", 1e-3}};
  Model model(mesh, o);
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.steps = 20;
  ro.record = false;
  const Eigen::VectorXd p = model.default_parameters();
  const Eigen::VectorXd x = sim.forward(p, ro);
  const Eigen::VectorXd dx = 0.05 * sim.velocities();
  Term* term = nullptr;
  for (const auto& t : model.terms())
    if (t->name() == "self_contact") term = t.get();
  ASSERT_NE(term, nullptr);
  auto per_call = [&](auto&& f) {
    const auto t0 = std::chrono::steady_clock::now();
    for (int r = 0; r < 50; ++r) f(r);
    return 1e3 * seconds_since(t0) / 50;
  };
  const double e = per_call([&](int r) { term->energy(x + (1e-9 * r) * dx, p); });
  const double m = per_call([&](int) { term->max_step(x, dx, p); });
  const double b = per_call([&](int) { term->begin_step(x, p, 0.05); });
  std::printf("circle1 self_contact per call: energy %.3f ms, max_step %.3f ms, begin_step %.3f ms\n", e, m, b);
}

}  // namespace
}  // namespace drapelab
