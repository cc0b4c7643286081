// A program that uses diffphd the way a downstream simulator would.
#include <diffphd/diffphd.hpp>

#include <cstdio>
#ifdef CONSUMER_HAS_CUDA
#include <diffphd/cuda/device_inverse_factor.hpp>
#endif

int main() {
  diffphd::TetMesh::Positions X(4, 3);
  X << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  diffphd::TetMesh::Elements T(1, 4);
  T << 0, 1, 2, 3;
  const diffphd::TetMesh mesh(X, T);
  const double v = mesh.total_volume();
  std::printf("diffphd %s: one tet of volume %.6f\n", diffphd::version(), v);
#ifdef CONSUMER_HAS_CUDA
  std::string why;
  std::printf("cuda unit linked; device available: %s\n",
              diffphd::cuda::device_available(&why) ? "yes" : why.c_str());
#endif
  return (v > 0.1666 && v < 0.1667) ? 0 : 1;
}
