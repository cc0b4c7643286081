// diffphd::cuda — device implementation of DeviceInverseFactor (see
// include/diffphd/cuda/device_inverse_factor.hpp and docs/cuda.md).
#include "diffphd/cuda/device_inverse_factor.hpp"

#include <cuda_runtime.h>
#include <cusparse.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <stdexcept>
#include <string>
#include <initializer_list>
#include <utility>

namespace diffphd {
namespace cuda {
namespace {

[[noreturn]] void throw_cuda(cudaError_t err, const char* call, const char* file, int line) {
  std::ostringstream os;
  os << file << ":" << line << ": CUDA call '" << call << "' failed: " << cudaGetErrorName(err)
     << " (" << cudaGetErrorString(err) << ")";
  throw std::runtime_error(os.str());
}

[[noreturn]] void throw_cusparse(cusparseStatus_t st, const char* call, const char* file,
                                 int line) {
  std::ostringstream os;
  os << file << ":" << line << ": cuSPARSE call '" << call << "' failed: status "
     << static_cast<int>(st) << " (" << cusparseGetErrorString(st) << ")";
  throw std::runtime_error(os.str());
}

// Error-checking macros: throw std::runtime_error naming file, line, the call and the
// CUDA / cuSPARSE error string.
#define check_cuda(expr)                                                    \
  do {                                                                      \
    const cudaError_t diffphd_err_ = (expr);                                \
    if (diffphd_err_ != cudaSuccess) {                                      \
      (void)cudaGetLastError(); /* clear a non-sticky error */              \
      ::diffphd::cuda::throw_cuda(diffphd_err_, #expr, __FILE__, __LINE__); \
    }                                                                       \
  } while (0)

#define check_cusparse(expr)                                                   \
  do {                                                                         \
    const cusparseStatus_t diffphd_st_ = (expr);                               \
    if (diffphd_st_ != CUSPARSE_STATUS_SUCCESS) {                              \
      ::diffphd::cuda::throw_cusparse(diffphd_st_, #expr, __FILE__, __LINE__); \
    }                                                                          \
  } while (0)

// Owning device allocation that only grows (no cudaMalloc once large enough).
struct DeviceBuffer {
  void* ptr = nullptr;
  std::size_t bytes = 0;

  DeviceBuffer() = default;
  DeviceBuffer(const DeviceBuffer&) = delete;
  DeviceBuffer& operator=(const DeviceBuffer&) = delete;
  ~DeviceBuffer() { release(); }

  void release() noexcept {
    if (ptr != nullptr) cudaFree(ptr);
    ptr = nullptr;
    bytes = 0;
  }
  // Ensures at least `need` bytes; returns true when the buffer was (re)allocated.
  bool reserve(std::size_t need) {
    need = std::max<std::size_t>(need, 16);  // never a zero-byte allocation
    if (need <= bytes) return false;
    release();
    check_cuda(cudaMalloc(&ptr, need));
    bytes = need;
    return true;
  }
  template <class T>
  T* as() const {
    return static_cast<T*>(ptr);
  }
};

// Restores the previously current device on scope exit.
class DeviceGuard {
 public:
  explicit DeviceGuard(int device) {
    if (cudaGetDevice(&prev_) != cudaSuccess) {
      (void)cudaGetLastError();
      prev_ = -1;
    }
    if (device >= 0 && device != prev_) check_cuda(cudaSetDevice(device));
  }
  ~DeviceGuard() {
    int cur = -1;
    if (prev_ >= 0 && cudaGetDevice(&cur) == cudaSuccess && cur != prev_) cudaSetDevice(prev_);
  }
  DeviceGuard(const DeviceGuard&) = delete;
  DeviceGuard& operator=(const DeviceGuard&) = delete;

 private:
  int prev_ = -1;
};

// Column-major (rows x cols, ld = rows) -> row-major (ld = cols), or the inverse with
// to_row_major = false.
__global__ void transpose_layout_kernel(const double* __restrict__ src, double* __restrict__ dst,
                                        long long rows, long long cols, bool to_row_major) {
  const long long total = rows * cols;
  for (long long idx = blockIdx.x * static_cast<long long>(blockDim.x) + threadIdx.x; idx < total;
       idx += static_cast<long long>(gridDim.x) * blockDim.x) {
    const long long i = idx % rows;  // row
    const long long j = idx / rows;  // column
    if (to_row_major) {
      dst[i * cols + j] = src[j * rows + i];
    } else {
      dst[j * rows + i] = src[i * cols + j];
    }
  }
}

void launch_transpose(const double* src, double* dst, long long rows, long long cols,
                      bool to_row_major) {
  const long long total = rows * cols;
  if (total == 0) return;
  const int threads = 256;
  const long long blocks = std::min<long long>((total + threads - 1) / threads, 65535LL * 8);
  transpose_layout_kernel<<<static_cast<unsigned>(blocks), threads>>>(src, dst, rows, cols,
                                                                      to_row_major);
  check_cuda(cudaGetLastError());
}

void validate_csr(const CsrView& m, const char* name) {
  std::ostringstream os;
  os << "DeviceInverseFactor::upload: " << name << ": ";
  if (m.rows <= 0 || m.cols <= 0 || m.nnz < 0) {
    os << "invalid shape " << m.rows << " x " << m.cols << " with nnz " << m.nnz;
    throw std::invalid_argument(os.str());
  }
  if (m.row_ptr == nullptr || (m.nnz > 0 && (m.col_ind == nullptr || m.values == nullptr))) {
    os << "null CSR array";
    throw std::invalid_argument(os.str());
  }
  if (m.row_ptr[0] != 0 || m.row_ptr[m.rows] != m.nnz) {
    os << "row_ptr must start at 0 and end at nnz (got " << m.row_ptr[0] << " .. "
       << m.row_ptr[m.rows] << ", nnz " << m.nnz << ")";
    throw std::invalid_argument(os.str());
  }
  for (int r = 0; r < m.rows; ++r) {
    if (m.row_ptr[r + 1] < m.row_ptr[r]) {
      os << "row_ptr decreases at row " << r;
      throw std::invalid_argument(os.str());
    }
  }
  for (int k = 0; k < m.nnz; ++k) {
    if (m.col_ind[k] < 0 || m.col_ind[k] >= m.cols) {
      os << "column index " << m.col_ind[k] << " out of range at entry " << k;
      throw std::invalid_argument(os.str());
    }
  }
}

constexpr cusparseSpMMAlg_t kSpmmAlg = CUSPARSE_SPMM_CSR_ALG2;
constexpr cusparseSpMVAlg_t kSpmvAlg = CUSPARSE_SPMV_ALG_DEFAULT;

}  // namespace

bool device_available(std::string* reason) {
  int count = 0;
  const cudaError_t err = cudaGetDeviceCount(&count);
  if (err != cudaSuccess) {
    (void)cudaGetLastError();
    if (reason != nullptr) {
      *reason = std::string("no CUDA device: cudaGetDeviceCount returned ") +
                cudaGetErrorName(err) + " (" + cudaGetErrorString(err) + ")";
    }
    return false;
  }
  if (count <= 0) {
    if (reason != nullptr) {
      *reason = "no CUDA device: cudaGetDeviceCount returned cudaSuccess with 0 devices";
    }
    return false;
  }
  if (reason != nullptr) reason->clear();
  return true;
}

struct DeviceInverseFactor::Impl {
  int device = -1;
  cusparseHandle_t handle = nullptr;
  int n = 0;
  long long nnz = 0;

  // CSR arrays of S and S^T.
  DeviceBuffer s_rp, s_ci, s_val, t_rp, t_ci, t_val;
  cusparseSpMatDescr_t matS = nullptr;
  cusparseSpMatDescr_t matSt = nullptr;

  // SpMV path (apply / apply_device): rebindable vector descriptors.
  cusparseDnVecDescr_t vec_in = nullptr;
  cusparseDnVecDescr_t vec_tmp = nullptr;
  cusparseDnVecDescr_t vec_out = nullptr;
  DeviceBuffer tmp;        // n doubles: S v for one column
  DeviceBuffer host_work;  // n * d doubles: staging for host apply()
  DeviceBuffer spmv_buf;

  // SpMM path (multiply_columns): row-major dense operands sized for spmm_k columns.
  int spmm_k = -1;
  DeviceBuffer mm_col;  // column-major staging for B and Y
  DeviceBuffer mm_b;    // B row-major
  DeviceBuffer mm_y;    // Y row-major
  cusparseDnMatDescr_t matB = nullptr;
  cusparseDnMatDescr_t matY = nullptr;
  DeviceBuffer spmm_buf;

  Impl() = default;
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;
  ~Impl() {
    int prev = -1;
    const bool switched = device >= 0 && cudaGetDevice(&prev) == cudaSuccess && prev != device &&
                          cudaSetDevice(device) == cudaSuccess;
    destroy_spmm();
    destroy_descriptors();
    if (handle != nullptr) cusparseDestroy(handle);
    for (DeviceBuffer* b : {&s_rp, &s_ci, &s_val, &t_rp, &t_ci, &t_val, &tmp, &host_work, &spmv_buf,
                            &mm_col, &mm_b, &mm_y, &spmm_buf}) {
      b->release();
    }
    if (switched) cudaSetDevice(prev);
    (void)cudaGetLastError();
  }

  void destroy_spmm() noexcept {
    if (matB != nullptr) cusparseDestroyDnMat(matB);
    if (matY != nullptr) cusparseDestroyDnMat(matY);
    matB = nullptr;
    matY = nullptr;
    spmm_k = -1;
  }
  void destroy_descriptors() noexcept {
    if (matS != nullptr) cusparseDestroySpMat(matS);
    if (matSt != nullptr) cusparseDestroySpMat(matSt);
    if (vec_in != nullptr) cusparseDestroyDnVec(vec_in);
    if (vec_tmp != nullptr) cusparseDestroyDnVec(vec_tmp);
    if (vec_out != nullptr) cusparseDestroyDnVec(vec_out);
    matS = matSt = nullptr;
    vec_in = vec_tmp = vec_out = nullptr;
  }

  void require_uploaded(const char* what) const {
    if (n <= 0) {
      throw std::logic_error(std::string("DeviceInverseFactor::") + what + ": no factor uploaded");
    }
  }

  void upload_csr(const CsrView& m, DeviceBuffer& rp, DeviceBuffer& ci, DeviceBuffer& val,
                  cusparseSpMatDescr_t* mat) {
    rp.reserve(sizeof(int) * (static_cast<std::size_t>(m.rows) + 1));
    ci.reserve(sizeof(int) * static_cast<std::size_t>(m.nnz));
    val.reserve(sizeof(double) * static_cast<std::size_t>(m.nnz));
    check_cuda(cudaMemcpy(rp.ptr, m.row_ptr, sizeof(int) * (static_cast<std::size_t>(m.rows) + 1),
                          cudaMemcpyHostToDevice));
    if (m.nnz > 0) {
      check_cuda(cudaMemcpy(ci.ptr, m.col_ind, sizeof(int) * static_cast<std::size_t>(m.nnz),
                            cudaMemcpyHostToDevice));
      check_cuda(cudaMemcpy(val.ptr, m.values, sizeof(double) * static_cast<std::size_t>(m.nnz),
                            cudaMemcpyHostToDevice));
    }
    check_cusparse(cusparseCreateCsr(mat, m.rows, m.cols, m.nnz, rp.ptr, ci.ptr, val.ptr,
                                     CUSPARSE_INDEX_32I, CUSPARSE_INDEX_32I,
                                     CUSPARSE_INDEX_BASE_ZERO, CUDA_R_64F));
  }

  void upload(const CsrView& S, const CsrView& St) {
    validate_csr(S, "S");
    validate_csr(St, "St");
    if (S.rows != S.cols || St.rows != S.cols || St.cols != S.rows || St.nnz != S.nnz) {
      std::ostringstream os;
      os << "DeviceInverseFactor::upload: S must be square and St its transpose (S " << S.rows
         << " x " << S.cols << " nnz " << S.nnz << ", St " << St.rows << " x " << St.cols << " nnz "
         << St.nnz << ")";
      throw std::invalid_argument(os.str());
    }

    if (handle == nullptr) check_cuda(cudaGetDevice(&device));  // later calls run on it
    n = 0;                                                      // not usable until fully uploaded
    nnz = 0;
    destroy_spmm();
    destroy_descriptors();
    if (handle == nullptr) check_cusparse(cusparseCreate(&handle));

    upload_csr(S, s_rp, s_ci, s_val, &matS);
    upload_csr(St, t_rp, t_ci, t_val, &matSt);

    const int nv = S.rows;
    tmp.reserve(sizeof(double) * static_cast<std::size_t>(nv));
    check_cuda(cudaMemset(tmp.ptr, 0, sizeof(double) * static_cast<std::size_t>(nv)));
    // All three vector descriptors start bound to `tmp`; apply rebinds them per column.
    check_cusparse(cusparseCreateDnVec(&vec_in, nv, tmp.ptr, CUDA_R_64F));
    check_cusparse(cusparseCreateDnVec(&vec_tmp, nv, tmp.ptr, CUDA_R_64F));
    check_cusparse(cusparseCreateDnVec(&vec_out, nv, tmp.ptr, CUDA_R_64F));

    const double one = 1.0, zero = 0.0;
    std::size_t size_s = 0, size_t_ = 0;
    check_cusparse(cusparseSpMV_bufferSize(handle, CUSPARSE_OPERATION_NON_TRANSPOSE, &one, matS,
                                           vec_in, &zero, vec_tmp, CUDA_R_64F, kSpmvAlg, &size_s));
    check_cusparse(cusparseSpMV_bufferSize(handle, CUSPARSE_OPERATION_NON_TRANSPOSE, &one, matSt,
                                           vec_tmp, &zero, vec_out, CUDA_R_64F, kSpmvAlg,
                                           &size_t_));
    spmv_buf.reserve(std::max(size_s, size_t_));

    n = nv;
    nnz = S.nnz;
  }

  // X = S^T (S V), device pointers, column-major n x d. dV == dX allowed.
  void apply_device(const double* dV, double* dX, int d) {
    const double one = 1.0, zero = 0.0;
    const std::size_t stride = static_cast<std::size_t>(n);
    for (int j = 0; j < d; ++j) {
      check_cusparse(cusparseDnVecSetValues(vec_in, const_cast<double*>(dV + j * stride)));
      check_cusparse(cusparseDnVecSetValues(vec_out, dX + j * stride));
      check_cusparse(cusparseSpMV(handle, CUSPARSE_OPERATION_NON_TRANSPOSE, &one, matS, vec_in,
                                  &zero, vec_tmp, CUDA_R_64F, kSpmvAlg, spmv_buf.ptr));
      check_cusparse(cusparseSpMV(handle, CUSPARSE_OPERATION_NON_TRANSPOSE, &one, matSt, vec_tmp,
                                  &zero, vec_out, CUDA_R_64F, kSpmvAlg, spmv_buf.ptr));
    }
  }

  // Sets up the SpMM descriptors, workspace and preprocess pass for K columns (only when
  // K differs from the previous call or after an upload).
  void prepare_spmm(int K) {
    if (K == spmm_k) return;
    destroy_spmm();
    const std::size_t bytes = sizeof(double) * static_cast<std::size_t>(n) * K;
    mm_col.reserve(bytes);
    mm_b.reserve(bytes);
    mm_y.reserve(bytes);
    // Row-major n x K (ld = K): the layout cuSPARSE documents as the fast path for CSR SpMM.
    check_cusparse(cusparseCreateDnMat(&matB, n, K, K, mm_b.ptr, CUDA_R_64F, CUSPARSE_ORDER_ROW));
    check_cusparse(cusparseCreateDnMat(&matY, n, K, K, mm_y.ptr, CUDA_R_64F, CUSPARSE_ORDER_ROW));
    const double one = 1.0, zero = 0.0;
    std::size_t size = 0;
    check_cusparse(cusparseSpMM_bufferSize(handle, CUSPARSE_OPERATION_NON_TRANSPOSE,
                                           CUSPARSE_OPERATION_NON_TRANSPOSE, &one, matS, matB,
                                           &zero, matY, CUDA_R_64F, kSpmmAlg, &size));
    spmm_buf.reserve(size);
    // Pattern analysis, amortised over all multiply_columns calls with this K. The same
    // workspace must be passed to every later cusparseSpMM call.
    check_cusparse(cusparseSpMM_preprocess(handle, CUSPARSE_OPERATION_NON_TRANSPOSE,
                                           CUSPARSE_OPERATION_NON_TRANSPOSE, &one, matS, matB,
                                           &zero, matY, CUDA_R_64F, kSpmmAlg, spmm_buf.ptr));
    spmm_k = K;
  }

  void multiply_columns(const double* B, int K, double* Y) {
    prepare_spmm(K);
    const std::size_t bytes = sizeof(double) * static_cast<std::size_t>(n) * K;
    check_cuda(cudaMemcpy(mm_col.ptr, B, bytes, cudaMemcpyHostToDevice));
    launch_transpose(mm_col.as<double>(), mm_b.as<double>(), n, K, /*to_row_major=*/true);
    const double one = 1.0, zero = 0.0;
    check_cusparse(cusparseSpMM(handle, CUSPARSE_OPERATION_NON_TRANSPOSE,
                                CUSPARSE_OPERATION_NON_TRANSPOSE, &one, matS, matB, &zero, matY,
                                CUDA_R_64F, kSpmmAlg, spmm_buf.ptr));
    launch_transpose(mm_y.as<double>(), mm_col.as<double>(), n, K, /*to_row_major=*/false);
    check_cuda(cudaMemcpy(Y, mm_col.ptr, bytes, cudaMemcpyDeviceToHost));
  }
};

DeviceInverseFactor::DeviceInverseFactor() : impl_(new Impl) {}
DeviceInverseFactor::~DeviceInverseFactor() = default;
DeviceInverseFactor::DeviceInverseFactor(DeviceInverseFactor&&) noexcept = default;
DeviceInverseFactor& DeviceInverseFactor::operator=(DeviceInverseFactor&&) noexcept = default;

void DeviceInverseFactor::upload(const CsrView& S, const CsrView& St) {
  if (!impl_) impl_.reset(new Impl);  // moved-from objects become usable again
  DeviceGuard guard(impl_->device);
  impl_->upload(S, St);
}

void DeviceInverseFactor::apply(const double* V, double* X, int d) const {
  if (d < 0) throw std::invalid_argument("DeviceInverseFactor::apply: negative d");
  if (!impl_) throw std::logic_error("DeviceInverseFactor::apply: moved-from object");
  impl_->require_uploaded("apply");
  if (d == 0) return;
  if (V == nullptr || X == nullptr) {
    throw std::invalid_argument("DeviceInverseFactor::apply: null pointer");
  }
  DeviceGuard guard(impl_->device);
  const std::size_t bytes = sizeof(double) * static_cast<std::size_t>(impl_->n) * d;
  impl_->host_work.reserve(bytes);
  double* work = impl_->host_work.as<double>();
  check_cuda(cudaMemcpy(work, V, bytes, cudaMemcpyHostToDevice));
  impl_->apply_device(work, work, d);
  check_cuda(cudaMemcpy(X, work, bytes, cudaMemcpyDeviceToHost));
}

void DeviceInverseFactor::apply_device(const double* dV, double* dX, int d) const {
  if (d < 0) throw std::invalid_argument("DeviceInverseFactor::apply_device: negative d");
  if (!impl_) throw std::logic_error("DeviceInverseFactor::apply_device: moved-from object");
  impl_->require_uploaded("apply_device");
  if (d == 0) return;
  if (dV == nullptr || dX == nullptr) {
    throw std::invalid_argument("DeviceInverseFactor::apply_device: null pointer");
  }
  DeviceGuard guard(impl_->device);
  impl_->apply_device(dV, dX, d);
  check_cuda(cudaStreamSynchronize(nullptr));
}

void DeviceInverseFactor::multiply_columns(const double* B, int K, double* Y) const {
  if (K < 0) throw std::invalid_argument("DeviceInverseFactor::multiply_columns: negative K");
  if (!impl_) throw std::logic_error("DeviceInverseFactor::multiply_columns: moved-from object");
  impl_->require_uploaded("multiply_columns");
  if (K == 0) return;
  if (B == nullptr || Y == nullptr) {
    throw std::invalid_argument("DeviceInverseFactor::multiply_columns: null pointer");
  }
  DeviceGuard guard(impl_->device);
  impl_->multiply_columns(B, K, Y);
}

int DeviceInverseFactor::rows() const {
  return impl_ ? impl_->n : 0;
}

long long DeviceInverseFactor::nnz() const {
  return impl_ ? impl_->nnz : 0;
}

}  // namespace cuda
}  // namespace diffphd
