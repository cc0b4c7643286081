// Tests for diffphd::cuda::DeviceInverseFactor. The GPU checks skip (with a WARN) when no
// CUDA device is present; the CPU reference and argument checks run everywhere.
#include <cuda_runtime.h>

#include <Eigen/Dense>
#include <Eigen/OrderingMethods>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <catch2/catch.hpp>
#include <diffphd/cuda/device_inverse_factor.hpp>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace {

using SpMat = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;
using SpMatRow = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

// 2D grid Laplacian (m x m nodes, 5-point stencil) plus a varying positive diagonal: SPD.
SpMat grid_spd(int m) {
  const int n = m * m;
  std::vector<Eigen::Triplet<double>> t;
  t.reserve(static_cast<std::size_t>(5) * n);
  for (int y = 0; y < m; ++y) {
    for (int x = 0; x < m; ++x) {
      const int i = y * m + x;
      double diag = 0.1 + 0.01 * (i % 7);
      const int nb[4][2] = {{x - 1, y}, {x + 1, y}, {x, y - 1}, {x, y + 1}};
      for (const auto& q : nb) {
        if (q[0] < 0 || q[0] >= m || q[1] < 0 || q[1] >= m) continue;
        t.emplace_back(i, q[1] * m + q[0], -1.0);
        diag += 1.0;
      }
      t.emplace_back(i, i, diag);
    }
  }
  SpMat A(n, n);
  A.setFromTriplets(t.begin(), t.end());
  return A;
}

struct Reference {
  SpMat A;
  Eigen::SimplicialLLT<SpMat, Eigen::Lower, Eigen::AMDOrdering<int>> llt;
  SpMatRow S;   // S = L^{-1} P, CSR
  SpMatRow St;  // S^T, CSR
};

// P A P^T = L L^T (Eigen: llt.permutationP() is P) and S = L^{-1} P, column by column.
void build_reference(int m, Reference& r) {
  r.A = grid_spd(m);
  r.llt.compute(r.A);
  REQUIRE(r.llt.info() == Eigen::Success);
  const int n = static_cast<int>(r.A.rows());
  std::vector<Eigen::Triplet<double>> t;
  Eigen::VectorXd e(n);
  for (int j = 0; j < n; ++j) {
    e.setZero();
    e(j) = 1.0;
    Eigen::VectorXd col = r.llt.permutationP() * e;
    r.llt.matrixL().solveInPlace(col);  // L is lower-triangular: col = L^{-1} P e_j
    for (int i = 0; i < n; ++i) {
      if (col(i) != 0.0) t.emplace_back(i, j, col(i));
    }
  }
  SpMat S(n, n);
  S.setFromTriplets(t.begin(), t.end());
  r.S = S;
  r.St = SpMat(S.transpose());
  r.S.makeCompressed();
  r.St.makeCompressed();
}

diffphd::cuda::CsrView view(const SpMatRow& M) {
  diffphd::cuda::CsrView v;
  v.rows = static_cast<int>(M.rows());
  v.cols = static_cast<int>(M.cols());
  v.nnz = static_cast<int>(M.nonZeros());
  v.row_ptr = M.outerIndexPtr();
  v.col_ind = M.innerIndexPtr();
  v.values = M.valuePtr();
  return v;
}

double rel_err(const Eigen::MatrixXd& x, const Eigen::MatrixXd& ref) {
  return (x - ref).norm() / ref.norm();
}

// Unit-spike columns: column j has a single 1 at row (5 + 37 j) mod n (distinct rows while
// gcd(37, n) == 1 and K <= n).
Eigen::MatrixXd unit_spikes(int n, int K) {
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(n, K);
  for (int j = 0; j < K; ++j) B((5 + 37 * j) % n, j) = 1.0;
  return B;
}

bool gpu_or_warn() {
  std::string reason;
  if (!diffphd::cuda::device_available(&reason)) {
    WARN("skipping GPU test: " << reason);
    return false;
  }
  return true;
}

constexpr int kGrid = 24;  // n = 576, gcd(37, 576) == 1

}  // namespace

TEST_CASE("CPU reference inverse factor satisfies S^T S = A^-1", "[cuda][reference]") {
  Reference r;
  build_reference(kGrid, r);
  const int n = static_cast<int>(r.A.rows());
  const Eigen::MatrixXd V = Eigen::MatrixXd::Random(n, 3);
  const Eigen::MatrixXd ref = r.llt.solve(V);
  const Eigen::MatrixXd X = r.St * (r.S * V);
  CHECK(rel_err(X, ref) <= 1e-10);
  // S is lower-triangular in permuted space: L^{-1} is lower-triangular.
  const SpMat SPt = SpMat(r.S) * r.llt.permutationPinv();
  CHECK(SpMat(SPt.triangularView<Eigen::StrictlyUpper>()).nonZeros() == 0);
}

TEST_CASE("DeviceInverseFactor argument checks need no GPU", "[cuda]") {
  diffphd::cuda::DeviceInverseFactor f;
  CHECK(f.rows() == 0);
  CHECK(f.nnz() == 0);
  std::vector<double> v(4, 1.0), x(4);
  CHECK_THROWS_AS(f.apply(v.data(), x.data(), 1), std::logic_error);
  CHECK_THROWS_AS(f.multiply_columns(v.data(), 1, x.data()), std::logic_error);

  // 2x2 S and a 3x3 "transpose": rejected before any CUDA call.
  const int rp2[] = {0, 1, 3};
  const int ci2[] = {0, 0, 1};
  const double va2[] = {1.0, 2.0, 3.0};
  const int rp3[] = {0, 1, 2, 3};
  const int ci3[] = {0, 1, 2};
  diffphd::cuda::CsrView S{2, 2, 3, rp2, ci2, va2};
  diffphd::cuda::CsrView bad{3, 3, 3, rp3, ci3, va2};
  CHECK_THROWS_AS(f.upload(S, bad), std::invalid_argument);
  const int ci_oob[] = {0, 0, 5};
  diffphd::cuda::CsrView oob{2, 2, 3, rp2, ci_oob, va2};
  CHECK_THROWS_AS(f.upload(oob, S), std::invalid_argument);

  std::string reason;
  if (!diffphd::cuda::device_available(&reason)) {
    CHECK(reason.find("no CUDA device") != std::string::npos);
    // A valid upload must fail loudly (std::runtime_error naming the call), not crash.
    const int rpt[] = {0, 2, 3};
    const int cit[] = {0, 1, 1};
    const double vat[] = {1.0, 2.0, 3.0};
    diffphd::cuda::CsrView St{2, 2, 3, rpt, cit, vat};
    CHECK_THROWS_AS(f.upload(S, St), std::runtime_error);
    CHECK(f.rows() == 0);
  }
}

TEST_CASE("DeviceInverseFactor matches the CPU inverse factor", "[cuda]") {
  if (!gpu_or_warn()) return;

  Reference r;
  build_reference(kGrid, r);
  const int n = static_cast<int>(r.A.rows());

  diffphd::cuda::DeviceInverseFactor f;
  f.upload(view(r.S), view(r.St));
  REQUIRE(f.rows() == n);
  REQUIRE(f.nnz() == r.S.nonZeros());

  SECTION("apply: X = S^T S V = A^-1 V") {
    for (int d = 1; d <= 3; ++d) {
      const Eigen::MatrixXd V = Eigen::MatrixXd::Random(n, d);
      const Eigen::MatrixXd ref = r.llt.solve(V);
      Eigen::MatrixXd X(n, d);
      f.apply(V.data(), X.data(), d);
      INFO("d = " << d);
      CHECK(rel_err(X, ref) <= 1e-10);
      Eigen::MatrixXd W = V;  // in-place (aliased) call
      f.apply(W.data(), W.data(), d);
      CHECK(rel_err(W, ref) <= 1e-10);
    }
  }

  SECTION("multiply_columns: Y = S B on unit spikes, full rank") {
    for (int K : {1, 7, 32, 32, 7}) {  // repeated K reuses the preprocess pass
      const Eigen::MatrixXd B = unit_spikes(n, K);
      const Eigen::MatrixXd ref = r.S * B;
      Eigen::MatrixXd Y(n, K);
      f.multiply_columns(B.data(), K, Y.data());
      INFO("K = " << K);
      CHECK(rel_err(Y, ref) <= 1e-12);
      Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(Y);
      CHECK(qr.rank() == K);
    }
  }

  SECTION("apply_device round trip and move") {
    const int d = 2;
    const Eigen::MatrixXd V = Eigen::MatrixXd::Random(n, d);
    const Eigen::MatrixXd ref = r.llt.solve(V);
    const std::size_t bytes = sizeof(double) * static_cast<std::size_t>(n) * d;
    double* dV = nullptr;
    double* dX = nullptr;
    REQUIRE(cudaMalloc(reinterpret_cast<void**>(&dV), bytes) == cudaSuccess);
    REQUIRE(cudaMalloc(reinterpret_cast<void**>(&dX), bytes) == cudaSuccess);
    REQUIRE(cudaMemcpy(dV, V.data(), bytes, cudaMemcpyHostToDevice) == cudaSuccess);

    diffphd::cuda::DeviceInverseFactor g(std::move(f));
    CHECK(g.rows() == n);
    g.apply_device(dV, dX, d);
    Eigen::MatrixXd X(n, d);
    REQUIRE(cudaMemcpy(X.data(), dX, bytes, cudaMemcpyDeviceToHost) == cudaSuccess);
    CHECK(rel_err(X, ref) <= 1e-10);

    g.apply_device(dV, dV, d);  // aliased
    REQUIRE(cudaMemcpy(X.data(), dV, bytes, cudaMemcpyDeviceToHost) == cudaSuccess);
    CHECK(rel_err(X, ref) <= 1e-10);

    cudaFree(dV);
    cudaFree(dX);
  }
}
