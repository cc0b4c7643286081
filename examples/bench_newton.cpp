// Explicit instantiation of the Newton reference runs of `diffphd bench` (its own unit).
#include "scene_bench.hpp"

template diffphd::cli::BenchRun diffphd::cli::bench_newton<2>(const diffphd::io::SceneSpec&,
                                                              const diffphd::NewtonOptions&, int);
template diffphd::cli::BenchRun diffphd::cli::bench_newton<3>(const diffphd::io::SceneSpec&,
                                                              const diffphd::NewtonOptions&, int);
