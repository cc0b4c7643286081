// diffphd::cuda — GPU application of the explicit inverse factor S = L^{-1} P.
//
// The PD system matrix A (nv x nv, SPD) is factored as P A P^T = L L^T. The explicit
// inverse factor S = L^{-1} P gives A^{-1} = S^T S, which is applied on the device as two
// sparse matrix-vector products x = S^T (S v) (cuSPARSE). The contact Delassus operator
// needs Y = S B for batches of unit-spike columns B = J^T, done with cusparseSpMM and
// CUSPARSE_SPMM_CSR_ALG2 (see docs/cuda.md).
//
// This header deliberately includes no CUDA header: everything CUDA lives behind a pimpl
// in cuda/device_inverse_factor.cu, so it compiles with a plain host C++17 compiler.
#pragma once

#include <memory>
#include <string>

namespace diffphd {
namespace cuda {

/// Non-owning view of a 0-based CSR matrix with double values and int indices.
/// row_ptr has rows + 1 entries (row_ptr[0] == 0, row_ptr[rows] == nnz); col_ind and
/// values have nnz entries. Column indices inside a row should be sorted.
struct CsrView {
  int rows = 0;
  int cols = 0;
  int nnz = 0;
  const int* row_ptr = nullptr;
  const int* col_ind = nullptr;
  const double* values = nullptr;
};

/// True when at least one CUDA device is usable. When false and reason != nullptr, *reason
/// receives a human-readable explanation (e.g. "no CUDA device: cudaGetDeviceCount returned
/// ..."). Never throws.
bool device_available(std::string* reason = nullptr);

/// Persistent device copy of the inverse factor S (nv x nv) and of S^T, with cuSPARSE
/// descriptors and work buffers that are reused across calls.
///
/// All methods run on the CUDA default stream of the current device and return only after
/// the result is complete. An instance is not safe for concurrent use from several threads
/// (its work buffers are shared between calls). Errors throw std::runtime_error (CUDA /
/// cuSPARSE failures) or std::invalid_argument (bad shapes / malformed CSR).
class DeviceInverseFactor {
 public:
  DeviceInverseFactor();
  ~DeviceInverseFactor();
  DeviceInverseFactor(const DeviceInverseFactor&) = delete;
  DeviceInverseFactor& operator=(const DeviceInverseFactor&) = delete;
  DeviceInverseFactor(DeviceInverseFactor&&) noexcept;
  DeviceInverseFactor& operator=(DeviceInverseFactor&&) noexcept;

  /// Copies S (nv x nv) and its transpose St (given explicitly, also CSR) into persistent
  /// device buffers and (re)creates the cuSPARSE descriptors. May be called again to
  /// replace the factor; previous device storage is released or reused.
  void upload(const CsrView& S, const CsrView& St);

  /// X = S^T (S V) for an nv x d block stored column-major on the host (leading dimension
  /// nv). V and X may alias. d == 0 is a no-op.
  void apply(const double* V, double* X, int d) const;

  /// Same as apply() with device pointers (column-major, leading dimension nv). dV and dX
  /// may alias.
  void apply_device(const double* dV, double* dX, int d) const;

  /// Y = S B for a dense column-major nv x K host matrix B (leading dimension nv); Y is
  /// nv x K column-major. Uses cusparseSpMM with CUSPARSE_SPMM_CSR_ALG2; the
  /// cusparseSpMM_preprocess pass is re-run only when K changes (or after upload()).
  void multiply_columns(const double* B, int K, double* Y) const;

  /// nv (0 before the first upload).
  int rows() const;
  /// Number of stored entries of S (0 before the first upload).
  long long nnz() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace cuda
}  // namespace diffphd
