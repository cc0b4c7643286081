// bench_local_step: per-element cost of the PD local step on the CPU (one thread).
//
// Over N random near-identity deformation gradients F = I + 0.15 U(-1, 1)^{3x3} it times
// sym_eig3 (of F^T F), svd_rv3, Corotated::project, Volume::project, NeoHookeanProx::project, the
// composite Energies<Corotated, Volume>::weighted_projection and weighted_differential, and, for
// comparison, the same composites evaluated the old way (each term's own project() /
// differential(), i.e. one SVD per term). Each figure is the median over repeats of
// (loop time / N), in ns per element; loop time is the thread's CPU time
// (CLOCK_THREAD_CPUTIME_ID), so time the machine spends on other processes is not counted.
//
// Usage: bench_local_step [--n N] [--reps R]   (defaults N = 100000, R = 7)
// docs/energies.md ("Cost") lists the figures.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <time.h>

#include <diffphd/core/small_matrix.hpp>
#include <diffphd/energy/energy.hpp>

#include "bench_args.hpp"

namespace {

using Mat3 = Eigen::Matrix3d;
using Vec3 = Eigen::Vector3d;
using Diff3 = Eigen::Matrix<double, 9, 9>;

double g_sink = 0.0;  // keeps the loops from being optimised away

double thread_cpu_ns() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e9 * static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec);
}

template <class Fn>
double median_ns_per_element(int n, int reps, Fn&& body) {
  std::vector<double> t;
  for (int r = 0; r < reps; ++r) {
    const double t0 = thread_cpu_ns();
    double acc = 0.0;
    for (int e = 0; e < n; ++e) acc += body(e);
    const double t1 = thread_cpu_ns();
    g_sink += acc;
    t.push_back((t1 - t0) / n);
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  int n = 100000, reps = 7;
  namespace ba = diffphd::bench_args;
  for (int i = 1; i < argc; ++i) {
    const std::string_view a = argv[i];
    if (a == "--n")  // 72 bytes of F per element: 10^8 is 7.2 GB
      n = static_cast<int>(ba::integer(
          "bench_local_step", a, ba::value("bench_local_step", argc, argv, i), 1, 100'000'000));
    else if (a == "--reps")
      reps = static_cast<int>(ba::integer(
          "bench_local_step", a, ba::value("bench_local_step", argc, argv, i), 1, 1'000'000));
    else {
      std::fprintf(stderr, "usage: bench_local_step [--n N] [--reps R]\n");
      return 2;
    }
  }

  std::mt19937 rng(12345);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Mat3> F(n);
  for (Mat3& f : F) {
    f.setIdentity();
    for (int i = 0; i < 9; ++i) f.data()[i] += 0.15 * u(rng);
  }

  using namespace diffphd;
  using E = Energies<Corotated, Volume>;
  ElementParams p;
  p.mu = 3.0e5;
  p.lambda = 1.2e6;
  const ProxMeans means{p.mu, p.lambda, 2.0 * p.mu + p.lambda};
  const double wc = Corotated::element_weight(p), wv = Volume::element_weight(p);

  struct Row {
    const char* name;
    double ns;
  };
  std::vector<Row> rows;
  auto run = [&](const char* name, auto&& body) {
    rows.push_back({name, median_ns_per_element(n, reps, body)});
  };

  run("sym_eig3 (F^T F)", [&](int e) {
    Vec3 l;
    Mat3 Q;
    sym_eig3(Mat3(F[e].transpose() * F[e]), l, Q);
    return l(0) + Q(0, 0);
  });
  run("svd_rv3", [&](int e) {
    Mat3 U, V;
    Vec3 s;
    svd_rv3(F[e], U, s, V);
    return s(0) + U(0, 0) + V(0, 0);
  });
  run("Corotated::project",
      [&](int e) { return Corotated::project<double, 3>(F[e], p, means)(0, 0); });
  run("Volume::project", [&](int e) { return Volume::project<double, 3>(F[e], p, means)(0, 0); });
  run("NeoHookeanProx::project",
      [&](int e) { return NeoHookeanProx::project<double, 3>(F[e], p, means)(0, 0); });
  run("Corotated+Volume, separate projects", [&](int e) {
    const Mat3 out = wc * Corotated::project<double, 3>(F[e], p, means) +
                     wv * Volume::project<double, 3>(F[e], p, means);
    return out(0, 0);
  });
  run("Energies<Corotated,Volume>::weighted_projection",
      [&](int e) { return E::weighted_projection<double, 3>(F[e], p, means)(0, 0); });
  run("Corotated+Volume, separate differentials", [&](int e) {
    const Diff3 D = wc * Corotated::differential<double, 3>(F[e], p, means) +
                    wv * Volume::differential<double, 3>(F[e], p, means);
    return D(0, 0);
  });
  run("Energies<Corotated,Volume>::weighted_differential",
      [&](int e) { return E::weighted_differential<double, 3>(F[e], p, means)(0, 0); });

  std::printf("bench_local_step: %d near-identity F (3x3, double), median of %d repeats\n", n,
              reps);
  for (const Row& r : rows) std::printf("  %-50s %9.1f ns/element\n", r.name, r.ns);
  std::printf("(checksum %.6e)\n", g_sink);
  return 0;
}
