// bench_factor: the factorization and the global-solve apply of the PD matrix A_s (eq. 31).
//
// For 2D and 3D structured grids (Kuhn split) and the Armadillo tet mesh it reports nv, nnz(A),
// nnz(L), nnz(S) and nnz(S)/nv^2, analyze+factor time of CHOLMOD (supernodal) and Eigen
// SimplicialLDLT (both METIS ordered) and their ratio, the time to apply A^-1 to an nv x 3 block
// by L solves (CHOLMOD, Eigen) and by the two CSR products S^T (S B) (eq. 33), and the bandwidth
// bound of each apply: bytes of the factor read per apply over the streaming bandwidth measured
// by a triad in the same run. Times are medians of repeats.
//
// Usage: bench_factor [--quick] [--csv FILE] [--json] [--reps N] [--max-s-nnz N] [--mesh PATH]
//   --quick      small sizes only (seconds)
//   --csv FILE   also write one CSV row per mesh to FILE
//   --json       print a JSON array to stdout (the table then goes to stderr)
//   --mesh PATH  TetGen mesh to use instead of data/meshes/armadillo (.node/.ele)
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

#include <diffphd/core/material.hpp>
#include <diffphd/core/mesh.hpp>
#include <diffphd/linalg/inverse_factor.hpp>
#include <diffphd/linalg/pd_matrix.hpp>
#include <diffphd/linalg/pd_system.hpp>
#include <diffphd/linalg/sparse_factor.hpp>

#if __has_include(<diffphd/io/tetgen.hpp>)
#include <diffphd/io/tetgen.hpp>
#define BENCH_HAVE_IO_TETGEN 1
#endif

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

// ---- meshes -------------------------------------------------------------------------------------

template <int Dim>
SimplicialMesh<Dim> grid_mesh(int n) {  // n^Dim cells on the unit cube, Kuhn split
  const int m = n + 1;
  const int nv = Dim == 2 ? m * m : m * m * m;
  VertexMatrix<Dim> X(nv, Dim);
  auto vid = [&](const std::array<int, 3>& c) {
    return Dim == 2 ? c[0] + m * c[1] : c[0] + m * (c[1] + m * c[2]);
  };
  for (int v = 0; v < nv; ++v) {
    int r = v;
    for (int a = 0; a < Dim; ++a, r /= m) X(v, a) = double(r % m) / n;
  }
  const int ncell = Dim == 2 ? n * n : n * n * n;
  const int per_cell = Dim == 2 ? 2 : 6;
  ElementMatrix<Dim> T(ncell * per_cell, Dim + 1);
  int e = 0;
  std::array<int, Dim> order;
  for (int cell = 0; cell < ncell; ++cell) {
    std::array<int, 3> base{0, 0, 0};
    int r = cell;
    for (int a = 0; a < Dim; ++a, r /= n) base[a] = r % n;
    for (int a = 0; a < Dim; ++a) order[a] = a;
    do {
      std::array<int, 3> c = base;
      T(e, 0) = vid(c);
      for (int s = 0; s < Dim; ++s) {
        ++c[order[s]];
        T(e, s + 1) = vid(c);
      }
      Mat<Dim> D;
      for (int s = 0; s < Dim; ++s) D.col(s) = (X.row(T(e, s + 1)) - X.row(T(e, 0))).transpose();
      if (D.determinant() < 0) std::swap(T(e, 1), T(e, 2));
      ++e;
    } while (std::next_permutation(order.begin(), order.end()));
  }
  return SimplicialMesh<Dim>(X, T);
}

/// Minimal TetGen reader (fallback when diffphd/io/tetgen.hpp is not there): first line
/// "n dim attrs markers", then "id x y z ..."; .ele "n 4 attrs" then "id a b c d ...".
bool read_tetgen_local(const std::string& base, SimplicialMesh<3>* mesh, std::string* why) {
  std::ifstream fn(base + ".node"), fe(base + ".ele");
  if (!fn || !fe) {
    *why = "cannot open " + base + ".node/.ele";
    return false;
  }
  auto next_line = [](std::ifstream& f, std::istringstream& ss) {
    std::string line;
    while (std::getline(f, line)) {
      const auto p = line.find('#');
      if (p != std::string::npos) line.resize(p);
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
      ss.clear();
      ss.str(line);
      return true;
    }
    return false;
  };
  std::istringstream ss;
  int nv = 0, dim = 0, ne = 0, k = 0;
  if (!next_line(fn, ss) || !(ss >> nv >> dim) || dim != 3) {
    *why = "bad .node header";
    return false;
  }
  VertexMatrix<3> X(nv, 3);
  int first = -1;
  for (int v = 0; v < nv; ++v) {
    int id;
    if (!next_line(fn, ss) || !(ss >> id >> X(v, 0) >> X(v, 1) >> X(v, 2))) {
      *why = "truncated .node";
      return false;
    }
    if (v == 0) first = id;
  }
  if (!next_line(fe, ss) || !(ss >> ne >> k) || k != 4) {
    *why = "bad .ele header";
    return false;
  }
  ElementMatrix<3> T(ne, 4);
  for (int e = 0; e < ne; ++e) {
    int id;
    if (!next_line(fe, ss) || !(ss >> id >> T(e, 0) >> T(e, 1) >> T(e, 2) >> T(e, 3))) {
      *why = "truncated .ele";
      return false;
    }
    for (int a = 0; a < 4; ++a) T(e, a) -= first;
    Mat<3> D;
    for (int s = 0; s < 3; ++s) D.col(s) = (X.row(T(e, s + 1)) - X.row(T(e, 0))).transpose();
    if (D.determinant() < 0) std::swap(T(e, 1), T(e, 2));
  }
  *mesh = SimplicialMesh<3>(X, T);
  return true;
}

// ---- bandwidth ----------------------------------------------------------------------------------

/// Streaming bandwidth (bytes/s) of the triad a = b + s c over three arrays of n doubles, counted
/// as 3 n 8 bytes (write-allocate traffic not counted), median of repeats.
double triad_bandwidth(size_t n, int threads) {
  std::vector<double> a(n), b(n, 1.0), c(n, 2.0);
  const double s = 0.5;
  std::vector<double> t;
  for (int r = 0; r < 9; ++r) {
    const double t0 = now_s();
#pragma omp parallel for schedule(static) num_threads(threads)
    for (long i = 0; i < static_cast<long>(n); ++i) a[i] = b[i] + s * c[i];
    t.push_back(now_s() - t0);
  }
  volatile double sink = a[n / 2];
  (void)sink;
  return 3.0 * 8.0 * double(n) / median(t);
}

// ---- one mesh ---------------------------------------------------------------------------------

struct Row {
  std::string mesh;
  int dim = 0;
  long long nv = 0, nnz_A = 0, nnz_L_cholmod = 0, nnz_L_eigen = 0, nnz_S = 0;
  double density_S = 0, density_L = 0;
  double cholmod_analyze = 0, cholmod_factor = 0, eigen_analyze = 0, eigen_factor = 0;
  double eigen_over_cholmod = 0;
  double apply_cholmod = 0, apply_eigen = 0, apply_S = 0, apply_S_1thread = 0, build_S = 0;
  double bytes_L = 0, bytes_S = 0, bound_L = 0, bound_S = 0;
  double eff_L = 0, eff_S = 0;  // bound / achieved (1 = at the bandwidth limit)
  std::string fastest, auto_pick;
};

template <int Dim>
Row run_mesh(const std::string& name, const SimplicialMesh<Dim>& mesh, double bandwidth, int reps,
             long long max_s_nnz, double auto_ratio) {
  Row row;
  row.mesh = name;
  row.dim = Dim;
  MaterialField mats(mesh.num_elements(), Material{1e5, 0.3, 1000.0, 0});
  const double xmid = mesh.bounding_box().center()[0];
  mats.assign_slab(mesh, 0, xmid, 1e30, Material{1e9, 0.3, 1000.0, 1});  // contrast 1e4
  PDMatrixParams p;
  p.h = 1e-2;
  p.beta0 = 1e-3;
  const SparseMatrix A = assemble_pd_matrix(mesh, mats, p);
  const long long n = A.rows();
  row.nv = n;
  row.nnz_A = A.nonZeros();
  const MatrixX B3 = MatrixX::Random(n, 3);

  SparseFactor chol(FactorBackend::Cholmod);
  double t0 = now_s();
  chol.analyze_pattern(A);
  row.cholmod_analyze = now_s() - t0;
  std::vector<double> tf;
  for (int r = 0; r < 3; ++r) {
    chol.factorize(A);
    tf.push_back(chol.factor_seconds());
  }
  row.cholmod_factor = median(tf);
  if (chol.info() != FactorStatus::Success) {
    std::cerr << name << ": CHOLMOD failed: " << chol.message() << "\n";
    return row;
  }
  row.nnz_L_cholmod = chol.nnz_L();

  SparseFactor eig(FactorBackend::EigenLDLT);
  t0 = now_s();
  eig.analyze_pattern(A);
  row.eigen_analyze = now_s() - t0;
  tf.clear();
  for (int r = 0; r < 3; ++r) {
    eig.factorize(A);
    tf.push_back(eig.factor_seconds());
  }
  row.eigen_factor = median(tf);
  row.nnz_L_eigen = eig.nnz_L();
  row.eigen_over_cholmod =
      (row.eigen_analyze + row.eigen_factor) / (row.cholmod_analyze + row.cholmod_factor);

  row.apply_cholmod = time_median(
      [&] {
        volatile double s = chol.solve(B3)(0, 0);
        (void)s;
      },
      reps);
  row.apply_eigen = time_median(
      [&] {
        volatile double s = eig.solve(B3)(0, 0);
        (void)s;
      },
      reps);

  const ExplicitFactor ef = chol.explicit_factor();
  row.nnz_S = inverse_factor_nnz(elimination_tree(ef.L));
  row.density_S = double(row.nnz_S) / double(n) / double(n);
  row.density_L = double(row.nnz_L_cholmod) / double(n) / double(n);
  // Bytes read per apply: L read twice (forward and backward) as values + row indices; S and
  // S^T each read once (values, column indices, row pointers). Right-hand sides not counted.
  row.bytes_L = 2.0 * (12.0 * double(row.nnz_L_cholmod) + 4.0 * double(n + 1));
  row.bytes_S = 2.0 * (12.0 * double(row.nnz_S) + 4.0 * double(n + 1));
  row.bound_L = row.bytes_L / bandwidth;
  row.bound_S = row.bytes_S / bandwidth;
  row.eff_L = row.bound_L / row.apply_cholmod;
  row.auto_pick = double(row.nnz_S) <= auto_ratio * double(row.nnz_L_cholmod) ? "inverse-factor"
                                                                              : "triangular-solve";
  if (row.nnz_S <= max_s_nnz) {
    InverseFactor S;
    S.build(ef);
    row.build_S = S.build_seconds();
    const MatrixX X = S.apply(B3);
    const MatrixX Xr = chol.solve(B3);
    const double err = (X - Xr).norm() / Xr.norm();
    if (err > 1e-8) std::cerr << name << ": S apply differs from the L solve by " << err << "\n";
    row.apply_S = time_median(
        [&] {
          volatile double s = S.apply(B3)(0, 0);
          (void)s;
        },
        reps);
    row.eff_S = row.bound_S / row.apply_S;
#ifdef _OPENMP
    // The same on one thread: a fair per-nonzero comparison with the (sequential) L solves, and
    // robust when other processes load the cores.
    const int saved = omp_get_max_threads();
    omp_set_num_threads(1);
    row.apply_S_1thread = time_median(
        [&] {
          volatile double s = S.apply(B3)(0, 0);
          (void)s;
        },
        reps);
    omp_set_num_threads(saved);
#else
    row.apply_S_1thread = row.apply_S;
#endif
  } else {
    std::cerr << name << ": nnz(S) = " << row.nnz_S << " above --max-s-nnz, S not built\n";
  }
  const double best_L = std::min(row.apply_cholmod, row.apply_eigen);
  const double best_S =
      row.apply_S_1thread > 0 ? std::min(row.apply_S, row.apply_S_1thread) : row.apply_S;
  row.fastest = (best_S > 0 && best_S < best_L)
                    ? "S two-SpMV"
                    : (row.apply_cholmod <= row.apply_eigen ? "CHOLMOD solve" : "Eigen solve");
  return row;
}

void print_table(std::ostream& os, const std::vector<Row>& rows) {
  char buf[512];
  std::snprintf(buf, sizeof buf,
                "%-16s %7s %9s %10s %10s %6s %6s | %8s %8s %6s | %8s %8s %8s %8s %6s %6s | %s\n",
                "mesh", "nv", "nnz(A)", "nnz(L)", "nnz(S)", "S/n^2", "L/n^2", "chol_s", "eigen_s",
                "ratio", "Lsolv_ms", "eig_ms", "S_ms", "S1t_ms", "L_eff", "S_eff", "auto");
  os << buf;
  for (const Row& r : rows) {
    std::snprintf(buf, sizeof buf,
                  "%-16s %7lld %9lld %10lld %10lld %5.2f%% %5.2f%% | %8.3f %8.3f %6.2f | %8.3f "
                  "%8.3f %8.3f %8.3f %5.0f%% %5.0f%% | %s (fastest: %s)\n",
                  r.mesh.c_str(), r.nv, r.nnz_A, r.nnz_L_cholmod, r.nnz_S, 100 * r.density_S,
                  100 * r.density_L, r.cholmod_analyze + r.cholmod_factor,
                  r.eigen_analyze + r.eigen_factor, r.eigen_over_cholmod, 1e3 * r.apply_cholmod,
                  1e3 * r.apply_eigen, 1e3 * r.apply_S, 1e3 * r.apply_S_1thread, 100 * r.eff_L,
                  100 * r.eff_S, r.auto_pick.c_str(), r.fastest.c_str());
    os << buf;
  }
}

const char* kCsvHeader =
    "mesh,dim,nv,nnz_A,nnz_L_cholmod,nnz_L_eigen,nnz_S,density_S,density_L,cholmod_analyze_s,"
    "cholmod_factor_s,eigen_analyze_s,eigen_factor_s,eigen_over_cholmod,apply_cholmod_s,"
    "apply_eigen_s,apply_S_s,apply_S_1thread_s,build_S_s,bytes_L,bytes_S,bound_L_s,bound_S_s,eff_L,"
    "eff_S,"
    "fastest,auto_pick,bandwidth_Bps";

void print_csv(std::ostream& os, const std::vector<Row>& rows, double bw) {
  os << kCsvHeader << "\n";
  for (const Row& r : rows)
    os << r.mesh << ',' << r.dim << ',' << r.nv << ',' << r.nnz_A << ',' << r.nnz_L_cholmod << ','
       << r.nnz_L_eigen << ',' << r.nnz_S << ',' << r.density_S << ',' << r.density_L << ','
       << r.cholmod_analyze << ',' << r.cholmod_factor << ',' << r.eigen_analyze << ','
       << r.eigen_factor << ',' << r.eigen_over_cholmod << ',' << r.apply_cholmod << ','
       << r.apply_eigen << ',' << r.apply_S << ',' << r.apply_S_1thread << ',' << r.build_S << ','
       << r.bytes_L << ',' << r.bytes_S << ',' << r.bound_L << ',' << r.bound_S << ',' << r.eff_L
       << ',' << r.eff_S << ',' << r.fastest << ',' << r.auto_pick << ',' << bw << "\n";
}

void print_json(std::ostream& os, const std::vector<Row>& rows, double bw, double bw1) {
  os << "{\"bandwidth_Bps\": " << bw << ", \"bandwidth_1thread_Bps\": " << bw1 << ", \"rows\": [\n";
  for (size_t i = 0; i < rows.size(); ++i) {
    const Row& r = rows[i];
    os << "  {\"mesh\": \"" << r.mesh << "\", \"dim\": " << r.dim << ", \"nv\": " << r.nv
       << ", \"nnz_A\": " << r.nnz_A << ", \"nnz_L_cholmod\": " << r.nnz_L_cholmod
       << ", \"nnz_L_eigen\": " << r.nnz_L_eigen << ", \"nnz_S\": " << r.nnz_S
       << ", \"density_S\": " << r.density_S << ", \"density_L\": " << r.density_L
       << ", \"cholmod_analyze_s\": " << r.cholmod_analyze
       << ", \"cholmod_factor_s\": " << r.cholmod_factor
       << ", \"eigen_analyze_s\": " << r.eigen_analyze << ", \"eigen_factor_s\": " << r.eigen_factor
       << ", \"eigen_over_cholmod\": " << r.eigen_over_cholmod
       << ", \"apply_cholmod_s\": " << r.apply_cholmod << ", \"apply_eigen_s\": " << r.apply_eigen
       << ", \"apply_S_s\": " << r.apply_S << ", \"apply_S_1thread_s\": " << r.apply_S_1thread
       << ", \"build_S_s\": " << r.build_S << ", \"bound_L_s\": " << r.bound_L
       << ", \"bound_S_s\": " << r.bound_S << ", \"eff_L\": " << r.eff_L
       << ", \"eff_S\": " << r.eff_S << ", \"fastest\": \"" << r.fastest << "\", \"auto_pick\": \""
       << r.auto_pick << "\"}" << (i + 1 < rows.size() ? ",\n" : "\n");
  }
  os << "]}\n";
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false, json = false;
  std::string csv, mesh_path = std::string(DIFFPHD_DATA_DIR) + "/meshes/armadillo";
  int reps = 21;
  long long max_s_nnz = 150'000'000;
  namespace ba = diffphd::bench_args;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&] { return ba::value("bench_factor", argc, argv, i); };
    if (a == "--quick")
      quick = true;
    else if (a == "--json")
      json = true;
    else if (a == "--csv")
      csv = value();
    else if (a == "--reps")
      reps = static_cast<int>(ba::integer("bench_factor", a, value(), 3, 1'000'000));
    else if (a == "--max-s-nnz")
      max_s_nnz = ba::integer("bench_factor", a, value(), 1, std::numeric_limits<long long>::max());
    else if (a == "--mesh")
      mesh_path = value();
    else if (a == "--help" || a == "-h") {
      std::cout << "usage: bench_factor [--quick] [--csv FILE] [--json] [--reps N] "
                   "[--max-s-nnz N] [--mesh BASENAME]\n";
      return 0;
    } else {
      std::cerr << "unknown option " << a << " (try --help)\n";
      return 2;
    }
  }
  std::ostream& out = json ? std::cerr : std::cout;
  int threads = 1;
#ifdef _OPENMP
  threads = omp_get_max_threads();
#endif
  const double bw = triad_bandwidth(size_t(1) << 25, threads);  // 3 x 256 MiB
  const double bw1 = triad_bandwidth(size_t(1) << 25, 1);
  const double auto_ratio = PDSystemOptions{}.auto_ratio;
  auto env = [](const char* k) {
    const char* v = std::getenv(k);
    return std::string(v ? v : "(unset)");
  };
  out << "OPENBLAS_NUM_THREADS=" << env("OPENBLAS_NUM_THREADS")
      << " OMP_WAIT_POLICY=" << env("OMP_WAIT_POLICY")
      << " (OpenBLAS pthreads spinning next to OpenMP slows the S products on few cores: "
         "docs/linalg.md Sec. 6)\n";
  out << "threads " << threads << ", triad bandwidth " << bw / 1e9 << " GB/s (" << bw1 / 1e9
      << " GB/s on 1 thread); Auto rule: inverse factor when nnz(S) <= " << auto_ratio
      << " nnz(L)\n";

  std::vector<Row> rows;
  auto report = [&](const Row& r) {
    rows.push_back(r);
    print_table(std::cerr, {r});
  };
  const std::vector<int> sizes3 = quick ? std::vector<int>{8, 12} : std::vector<int>{16, 24, 32};
  const std::vector<int> sizes2 = quick ? std::vector<int>{32, 64} : std::vector<int>{64, 128, 250};
  for (int s : sizes2)
    report(run_mesh<2>("grid2d-" + std::to_string(s) + "^2", grid_mesh<2>(s - 1), bw, reps,
                       max_s_nnz, auto_ratio));
  for (int s : sizes3)
    report(run_mesh<3>("grid3d-" + std::to_string(s) + "^3", grid_mesh<3>(s - 1), bw, reps,
                       max_s_nnz, auto_ratio));
  {
    SimplicialMesh<3> arm;
    std::string why;
    bool ok = false;
#ifdef BENCH_HAVE_IO_TETGEN
    try {
      arm = diffphd::io::read_tetgen<3>(mesh_path);
      ok = true;
    } catch (const std::exception& e) {
      why = e.what();
    }
#endif
    if (!ok) ok = read_tetgen_local(mesh_path, &arm, &why);
    if (ok)
      report(run_mesh<3>("armadillo", arm, bw, reps, max_s_nnz, auto_ratio));
    else
      out << "armadillo skipped: " << why << "\n";
  }
  out << "\n";
  print_table(out, rows);
  if (!csv.empty()) {
    std::ofstream f(csv);
    print_csv(f, rows, bw);
  }
  if (json) print_json(std::cout, rows, bw, bw1);
  return 0;
}
