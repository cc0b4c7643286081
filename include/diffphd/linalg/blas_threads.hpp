#pragma once
/// \file blas_threads.hpp
/// \brief The thread count of the BLAS that CHOLMOD calls (OpenBLAS on Debian), read and set at
/// run time.
///
/// OpenBLAS's pthread build keeps its own worker threads, which spin while they wait. Beside the
/// solver's OpenMP element loops they compete for the same cores: on the 2-core development
/// machine `diffphd run scenes/ball_drop.json --frames 30` took 21.5 ms per step (median) with
/// OpenBLAS's default thread count and 7.1 ms with one BLAS thread (docs/linalg.md). The
/// supernodal solves of the PD matrix are small; one BLAS thread is the right default for the
/// solver. The command-line tool sets it unless OPENBLAS_NUM_THREADS or GOTO_NUM_THREADS is set;
/// a program that includes the library decides for itself:
///
/// \code
/// if (!diffphd::blas_threads_from_environment()) diffphd::set_blas_threads(1);
/// \endcode
///
/// The functions look OpenBLAS's entry points up in the running process (dlsym), so they link
/// against any BLAS and do nothing where the BLAS is not OpenBLAS.

#include <cstdlib>

#include <dlfcn.h>

namespace diffphd {

namespace detail {
template <class F>
F openblas_symbol(const char* name) {
  return reinterpret_cast<F>(dlsym(RTLD_DEFAULT, name));
}
}  // namespace detail

/// OpenBLAS's thread count, or -1 when the process's BLAS is not OpenBLAS (or not loaded).
inline int blas_threads() {
  auto get = detail::openblas_symbol<int (*)()>("openblas_get_num_threads");
  return get ? get() : -1;
}

/// Sets OpenBLAS's thread count (n >= 1); false when the BLAS is not OpenBLAS or n < 1.
inline bool set_blas_threads(int n) {
  if (n < 1) return false;
  auto set = detail::openblas_symbol<void (*)(int)>("openblas_set_num_threads");
  if (!set) return false;
  set(n);
  return true;
}

/// True when the user chose OpenBLAS's thread count through its environment variables
/// (OPENBLAS_NUM_THREADS or GOTO_NUM_THREADS, non-empty); OMP_NUM_THREADS, which OpenBLAS also
/// reads, is taken as the choice for the element loops, not for the BLAS.
inline bool blas_threads_from_environment() {
  for (const char* v : {"OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS"}) {
    const char* s = std::getenv(v);
    if (s && *s) return true;
  }
  return false;
}

}  // namespace diffphd
