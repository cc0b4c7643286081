// bench_cuda_inverse_factor: the global-solve apply A^-1 B = S^T (S B) (eq. 33) on the GPU
// (diffphd::cuda::DeviceInverseFactor, cuSPARSE) against the CPU: CHOLMOD's triangular solves and
// the CPU two-SpMV apply of the same S (InverseFactor), and the Delassus product Y = S J^T on K
// unit-spike columns (multiply_columns against InverseFactor::multiply).
//
// Meshes: boxes of k^3 cells (Kuhn split, 6 tets per cell) and the Armadillo tet mesh, with a
// 10^4 stiffness slab (as bench_factor). Each row gives the relative error of every GPU result
// against the CPU one (CHOLMOD for apply, InverseFactor::multiply for the spikes) beside its
// median time. GPU times: `gpu_host` includes the host<->device copies of B and X, `gpu_dev`
// takes device-resident B and X (apply_device, what an on-device solver loop would pay).
//
// Usage: bench_cuda_inverse_factor [--csv FILE] [--reps N] [--max-s-nnz N] [--boxes 8,12,16]
//                                  [--mesh PATH | --no-mesh] [--spikes K]
// Without a CUDA device it prints why and exits 0 (nothing is timed).
#include <cuda_runtime.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/cuda/device_inverse_factor.hpp>
#include <diffphd/io/generators.hpp>
#include <diffphd/io/tetgen.hpp>
#include <diffphd/linalg/inverse_factor.hpp>
#include <diffphd/linalg/pd_matrix.hpp>
#include <diffphd/linalg/sparse_factor.hpp>

#include "bench_args.hpp"
#include "bench_timing.hpp"

#ifndef DIFFPHD_DATA_DIR
#define DIFFPHD_DATA_DIR "data"
#endif

using namespace diffphd;

namespace {

using bench::median;
using bench::now_s;
using bench::time_median;

void check(cudaError_t e, const char* what) {
  if (e != cudaSuccess) {
    std::cerr << what << ": " << cudaGetErrorString(e) << "\n";
    std::exit(1);
  }
}

cuda::CsrView view(Index rows, Index cols, long long nnz, const Index* rp, const Index* ci,
                   const double* v) {
  return cuda::CsrView{rows, cols, static_cast<int>(nnz), rp, ci, v};
}

struct Row {
  std::string mesh;
  long long nv = 0, nnz_L = 0, nnz_S = 0;
  double cholmod = 0, cpu_S = 0, gpu_host = 0, gpu_dev = 0;
  double err_cpu_S = 0, err_host = 0, err_dev = 0;
  int K = 0;
  double cpu_spikes = 0, gpu_spikes = 0, err_spikes = 0;
  bool skipped = false;
};

Row run_mesh(const std::string& name, const SimplicialMesh<3>& mesh, int reps, long long max_s_nnz,
             int K) {
  Row row;
  row.mesh = name;
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000.0, 0});
  const double xmid = mesh.bounding_box().center()[0];
  mats.assign_slab(mesh, 0, xmid, 1e30, Material{1e9, 0.3, 1000.0, 1});  // contrast 1e4
  PDMatrixParams p;
  p.h = 1e-2;
  p.beta0 = 1e-3;
  const SparseMatrix A = assemble_pd_matrix(mesh, mats, p);
  const Index n = static_cast<Index>(A.rows());
  row.nv = n;
  SparseFactor chol(FactorBackend::Cholmod);
  chol.analyze_pattern(A);
  chol.factorize(A);
  if (chol.info() != FactorStatus::Success) {
    std::cerr << name << ": CHOLMOD failed: " << chol.message() << "\n";
    std::exit(1);
  }
  row.nnz_L = chol.nnz_L();
  const ExplicitFactor ef = chol.explicit_factor();
  row.nnz_S = inverse_factor_nnz(elimination_tree(ef.L));
  if (row.nnz_S > max_s_nnz) {
    std::cerr << name << ": nnz(S) = " << row.nnz_S << " above --max-s-nnz, skipped\n";
    row.skipped = true;
    return row;
  }
  InverseFactor S;
  S.build(ef);

  const MatrixX B = MatrixX::Random(n, 3);
  const MatrixX Xref = chol.solve(B);
  const double ref_norm = Xref.norm();
  row.cholmod = time_median([&] { volatile double s = chol.solve(B)(0, 0); (void)s; }, reps);
  row.err_cpu_S = (S.apply(B) - Xref).norm() / ref_norm;
  row.cpu_S = time_median([&] { volatile double s = S.apply(B)(0, 0); (void)s; }, reps);

  cuda::DeviceInverseFactor g;
  g.upload(view(n, n, S.nnz(), S.S_row_ptr(), S.S_col_ind(), S.S_values()),
           view(n, n, S.nnz(), S.St_row_ptr(), S.St_col_ind(), S.St_values()));
  MatrixX X(n, 3);
  g.apply(B.data(), X.data(), 3);
  row.err_host = (X - Xref).norm() / ref_norm;
  row.gpu_host = time_median([&] { g.apply(B.data(), X.data(), 3); }, reps);

  const size_t bytes = sizeof(double) * static_cast<size_t>(n) * 3;
  double *dB = nullptr, *dX = nullptr;
  check(cudaMalloc(reinterpret_cast<void**>(&dB), bytes), "cudaMalloc");
  check(cudaMalloc(reinterpret_cast<void**>(&dX), bytes), "cudaMalloc");
  check(cudaMemcpy(dB, B.data(), bytes, cudaMemcpyHostToDevice), "cudaMemcpy");
  row.gpu_dev = time_median([&] { g.apply_device(dB, dX, 3); }, reps);
  check(cudaMemcpy(X.data(), dX, bytes, cudaMemcpyDeviceToHost), "cudaMemcpy");
  row.err_dev = (X - Xref).norm() / ref_norm;
  cudaFree(dB);
  cudaFree(dX);

  row.K = std::min<int>(K, n);
  MatrixX J = MatrixX::Zero(n, row.K);
  for (int j = 0; j < row.K; ++j) J((5 + 37LL * j) % n, j) = 1.0;
  const MatrixX Yref = S.multiply(J);
  MatrixX Y(n, row.K);
  g.multiply_columns(J.data(), row.K, Y.data());
  row.err_spikes = (Y - Yref).norm() / Yref.norm();
  row.cpu_spikes = time_median([&] { volatile double s = S.multiply(J)(0, 0); (void)s; }, reps);
  row.gpu_spikes = time_median([&] { g.multiply_columns(J.data(), row.K, Y.data()); }, reps);
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  std::string csv, mesh_path = std::string(DIFFPHD_DATA_DIR) + "/meshes/armadillo";
  int reps = 50, K = 64;
  long long max_s_nnz = 400000000LL;
  std::vector<int> boxes{8, 12, 16, 24};
  bool use_mesh = true;
  namespace ba = diffphd::bench_args;
  constexpr const char* prog = "bench_cuda_inverse_factor";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&] { return ba::value(prog, argc, argv, i); };
    if (a == "--csv")
      csv = next();
    else if (a == "--reps")
      reps = static_cast<int>(ba::integer(prog, a, next(), 1, 1'000'000));
    else if (a == "--max-s-nnz")
      max_s_nnz = ba::integer(prog, a, next(), 1, std::numeric_limits<long long>::max());
    else if (a == "--boxes")
      boxes = ba::integer_list(prog, a, next(), 1, 1000);
    else if (a == "--mesh")
      mesh_path = next();
    else if (a == "--no-mesh")
      use_mesh = false;
    else if (a == "--spikes")
      K = static_cast<int>(ba::integer(prog, a, next(), 1, 1'000'000));
    else {
      std::cerr << "unknown argument " << a << "\n";
      return 2;
    }
  }
  std::string reason;
  if (!cuda::device_available(&reason)) {
    std::cout << "bench_cuda_inverse_factor: skipped, " << reason << "\n";
    return 0;
  }
  cudaDeviceProp prop{};
  check(cudaGetDeviceProperties(&prop, 0), "cudaGetDeviceProperties");
  std::cout << "device: " << prop.name << "\n";

  std::vector<Row> rows;
  for (int k : boxes) {
    const auto mesh = make_box(Vec<3>(0, 0, 0), Vec<3>(1, 1, 1), Eigen::Vector3i(k, k, k));
    rows.push_back(run_mesh("box" + std::to_string(k), mesh, reps, max_s_nnz, K));
    std::cerr << "done " << rows.back().mesh << "\n";
  }
  if (use_mesh) rows.push_back(run_mesh("armadillo", io::read_tetgen<3>(mesh_path), reps, max_s_nnz, K));

  const char* header =
      "mesh,nv,nnz_L,nnz_S,cholmod_solve_s,cpu_S_apply_s,gpu_apply_host_s,gpu_apply_device_s,"
      "err_cpu_S,err_gpu_host,err_gpu_device,K,cpu_S_spikes_s,gpu_spikes_s,err_gpu_spikes";
  std::ostringstream out;
  out << header << "\n";
  for (const Row& r : rows) {
    if (r.skipped) continue;
    char buf[512];
    std::snprintf(buf, sizeof buf,
                  "%s,%lld,%lld,%lld,%.4g,%.4g,%.4g,%.4g,%.2e,%.2e,%.2e,%d,%.4g,%.4g,%.2e\n",
                  r.mesh.c_str(), r.nv, r.nnz_L, r.nnz_S, r.cholmod, r.cpu_S, r.gpu_host,
                  r.gpu_dev, r.err_cpu_S, r.err_host, r.err_dev, r.K, r.cpu_spikes, r.gpu_spikes,
                  r.err_spikes);
    out << buf;
  }
  std::cout << out.str();
  for (const Row& r : rows) {
    if (r.skipped) continue;
    std::printf("%-10s nv %7lld  apply(3 rhs): CHOLMOD %.3g ms, CPU S %.3g ms, GPU %.3g ms "
                "(device-resident %.3g ms) = %.1fx CHOLMOD; spikes K=%d: CPU %.3g ms, GPU %.3g ms\n",
                r.mesh.c_str(), r.nv, 1e3 * r.cholmod, 1e3 * r.cpu_S, 1e3 * r.gpu_host,
                1e3 * r.gpu_dev, r.cholmod / r.gpu_dev, r.K, 1e3 * r.cpu_spikes,
                1e3 * r.gpu_spikes);
  }
  if (!csv.empty()) {
    std::ofstream f(csv);
    f << out.str();
  }
  return 0;
}
