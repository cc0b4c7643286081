#pragma once
/// \file checkpoint.hpp
/// \brief Binary checkpoints of a SolverState / SceneState (state.hpp): exact doubles, so a
/// run restored from one continues bitwise equal to an uninterrupted run.
///
/// \code
/// diffphd::write_checkpoint_file("run.ckpt", sim.state());          // atomic (tmp + rename)
/// ...
/// sim2.set_state(diffphd::read_checkpoint_file<3>("run.ckpt"));     // a solver built alike
/// \endcode
///
/// Format (version 1, host byte order, checked on reading): the 8 bytes "DPHDSTAT", u32
/// version, u32 byte-order mark 0x01020304, u32 Dim, u32 kind (0 SolverState, 1 SceneState),
/// u64 #V, u64 #E, f64 time, #V*Dim f64 positions, velocities and external forces (VertexMatrix
/// storage order), #E f64 activations, u64 n + n f64 previous iterate, u64 drivers and per
/// driver: u32 kind, u32 release_at_stop, f64 start, stop, angular_velocity, axis[3],
/// center[3], velocity[3], u64 n, n i64 vertices, n*Dim f64 reference; for a SceneState then
/// u64 n + n u8 drivers_added, u64 n + n f64 group activations. Every count is checked against
/// the bytes left before anything is allocated.
#include <cstdint>
#include <cstring>
#include <fstream>
#include <istream>
#include <ostream>
#include <string>
#include <vector>

#include "../core/errors.hpp"
#include "../io/atomic_file.hpp"
#include "state.hpp"

namespace diffphd {

namespace detail {

inline constexpr char kCheckpointMagic[8] = {'D', 'P', 'H', 'D', 'S', 'T', 'A', 'T'};
inline constexpr std::uint32_t kCheckpointVersion = 2;  // 2: hessian_iterate
inline constexpr std::uint32_t kByteOrderMark = 0x01020304;

class CheckpointWriter {
 public:
  explicit CheckpointWriter(std::ostream& out) : out_(out) {}
  template <class T>
  void put(T x) {
    out_.write(reinterpret_cast<const char*>(&x), sizeof x);
  }
  void bytes(const char* p, std::size_t n) { out_.write(p, static_cast<std::streamsize>(n)); }
  void doubles(const double* p, std::size_t n) {
    out_.write(reinterpret_cast<const char*>(p), static_cast<std::streamsize>(n * sizeof(double)));
  }
  void vector(const VectorX& v) {
    put<std::uint64_t>(static_cast<std::uint64_t>(v.size()));
    doubles(v.data(), static_cast<std::size_t>(v.size()));
  }

 private:
  std::ostream& out_;
};

class CheckpointReader {
 public:
  /// `what` names the source in error messages (a file name).
  CheckpointReader(std::istream& in, std::string what) : in_(in), what_(std::move(what)) {
    const auto here = in_.tellg();
    if (here >= 0) {
      in_.seekg(0, std::ios::end);
      left_ = static_cast<std::uint64_t>(in_.tellg() - here);
      in_.seekg(here);
    } else {
      left_ = UINT64_MAX;  // not seekable: reads still fail cleanly at the end
    }
  }
  template <class T>
  T get() {
    T x{};
    raw(&x, sizeof x);
    return x;
  }
  void doubles(double* p, std::uint64_t n) { raw(p, n * sizeof(double)); }
  /// A count of items of `size` bytes each that must fit in the bytes left.
  std::uint64_t count(std::size_t size) {
    const auto n = get<std::uint64_t>();
    if (size > 0 && n > left_ / size) fail("a count of " + std::to_string(n) + " exceeds the file");
    return n;
  }
  VectorX vector() {
    const std::uint64_t n = count(sizeof(double));
    VectorX v(static_cast<Index>(n));
    doubles(v.data(), n);
    return v;
  }
  [[noreturn]] void fail(const std::string& why) const {
    throw InputError("not a readable diffphd checkpoint: " + why, what_);
  }

 private:
  void raw(void* p, std::uint64_t bytes) {
    if (bytes > left_) fail("truncated");
    in_.read(static_cast<char*>(p), static_cast<std::streamsize>(bytes));
    if (!in_) fail("truncated");
    left_ -= bytes;
  }
  std::istream& in_;
  std::string what_;
  std::uint64_t left_ = 0;
};

template <int Dim>
void write_solver_state(CheckpointWriter& w, const SolverState<Dim>& s, std::uint32_t kind) {
  const Index nv = s.positions.rows();
  if (s.velocities.rows() != nv || s.external_forces.rows() != nv)
    throw InputError("write_checkpoint: positions, velocities and forces differ in size");
  w.bytes(kCheckpointMagic, sizeof kCheckpointMagic);
  w.put(kCheckpointVersion);
  w.put(kByteOrderMark);
  w.put<std::uint32_t>(Dim);
  w.put(kind);
  w.put<std::uint64_t>(static_cast<std::uint64_t>(nv));
  w.put<std::uint64_t>(static_cast<std::uint64_t>(s.activations.size()));
  w.put(s.time);
  for (const VertexMatrix<Dim>* m : {&s.positions, &s.velocities, &s.external_forces})
    w.doubles(m->data(), static_cast<std::size_t>(m->size()));
  w.doubles(s.activations.data(), static_cast<std::size_t>(s.activations.size()));
  w.vector(s.previous_iterate);
  w.vector(s.hessian_iterate);
  w.put<std::uint64_t>(s.drivers.size());
  for (const DriverState<Dim>& d : s.drivers) {
    const Driver<Dim>& r = d.driver;
    w.put<std::uint32_t>(static_cast<std::uint32_t>(r.kind));
    w.put<std::uint32_t>(r.release_at_stop ? 1 : 0);
    for (double x : {r.start, r.stop, r.angular_velocity}) w.put(x);
    for (const Vec<3>* v : {&r.axis, &r.center, &r.velocity}) w.doubles(v->data(), 3);
    w.put<std::uint64_t>(r.vertices.size());
    for (Index v : r.vertices) w.put<std::int64_t>(v);
    w.doubles(d.reference.data(), static_cast<std::size_t>(d.reference.size()));
  }
}

template <int Dim>
SolverState<Dim> read_solver_state(CheckpointReader& r, std::uint32_t kind) {
  char magic[8];
  for (char& c : magic) c = r.get<char>();
  if (std::memcmp(magic, kCheckpointMagic, 8) != 0) r.fail("bad magic");
  const auto version = r.get<std::uint32_t>();
  if (version != kCheckpointVersion)
    r.fail("version " + std::to_string(version) + ", this build reads " +
           std::to_string(kCheckpointVersion));
  if (r.get<std::uint32_t>() != kByteOrderMark) r.fail("written on a machine of other byte order");
  const auto dim = r.get<std::uint32_t>();
  if (dim != Dim) r.fail(std::to_string(dim) + "D state, expected " + std::to_string(Dim) + "D");
  if (r.get<std::uint32_t>() != kind)
    r.fail(kind == 1 ? "a solver state, expected a scene state" : "a scene state, expected a solver state");
  SolverState<Dim> s;
  const Index nv = static_cast<Index>(r.count(3 * Dim * sizeof(double)));
  const Index ne = static_cast<Index>(r.count(sizeof(double)));
  s.time = r.get<double>();
  for (VertexMatrix<Dim>* m : {&s.positions, &s.velocities, &s.external_forces}) {
    m->resize(nv, Dim);
    r.doubles(m->data(), static_cast<std::uint64_t>(m->size()));
  }
  s.activations.resize(ne);
  r.doubles(s.activations.data(), static_cast<std::uint64_t>(ne));
  s.previous_iterate = r.vector();
  s.hessian_iterate = r.vector();
  const std::uint64_t nd = r.count(2 * sizeof(std::uint32_t) + 12 * sizeof(double) + 8);
  for (std::uint64_t i = 0; i < nd; ++i) {
    DriverState<Dim> d;
    const auto k = r.get<std::uint32_t>();
    if (k > 2) r.fail("unknown driver kind " + std::to_string(k));
    d.driver.kind = static_cast<typename Driver<Dim>::Kind>(k);
    d.driver.release_at_stop = r.get<std::uint32_t>() != 0;
    for (double* x : {&d.driver.start, &d.driver.stop, &d.driver.angular_velocity})
      *x = r.get<double>();
    for (Vec<3>* v : {&d.driver.axis, &d.driver.center, &d.driver.velocity}) r.doubles(v->data(), 3);
    const std::uint64_t n = r.count(sizeof(std::int64_t) + Dim * sizeof(double));
    d.driver.vertices.resize(n);
    for (Index& v : d.driver.vertices) v = static_cast<Index>(r.get<std::int64_t>());
    d.reference.resize(static_cast<Index>(n), Dim);
    r.doubles(d.reference.data(), n * Dim);
    s.drivers.push_back(std::move(d));
  }
  return s;
}

}  // namespace detail

/// Writes `s` (see the file comment for the format).
template <int Dim>
void write_checkpoint(std::ostream& out, const SolverState<Dim>& s) {
  detail::CheckpointWriter w(out);
  detail::write_solver_state(w, s, 0);
}

/// Writes `s` (a SceneRunner's state).
template <int Dim>
void write_checkpoint(std::ostream& out, const SceneState<Dim>& s) {
  detail::CheckpointWriter w(out);
  detail::write_solver_state(w, s.solver, 1);
  w.put<std::uint64_t>(s.drivers_added.size());
  for (bool b : s.drivers_added) w.put<std::uint8_t>(b ? 1 : 0);
  w.vector(s.group_activations);
}

/// Reads what write_checkpoint(out, SolverState) wrote. `what` names the source in errors.
/// \throws InputError (naming `what`) on a bad magic, version, byte order, dimension or kind,
///   or a truncated stream
template <int Dim>
SolverState<Dim> read_checkpoint(std::istream& in, const std::string& what = "checkpoint") {
  detail::CheckpointReader r(in, what);
  return detail::read_solver_state<Dim>(r, 0);
}

/// Reads what write_checkpoint(out, SceneState) wrote.
template <int Dim>
SceneState<Dim> read_scene_checkpoint(std::istream& in, const std::string& what = "checkpoint") {
  detail::CheckpointReader r(in, what);
  SceneState<Dim> s;
  s.solver = detail::read_solver_state<Dim>(r, 1);
  s.drivers_added.resize(r.count(1));
  for (std::size_t i = 0; i < s.drivers_added.size(); ++i)
    s.drivers_added[i] = r.get<std::uint8_t>() != 0;
  s.group_activations = r.vector();
  return s;
}

/// Writes a checkpoint file atomically (a temporary file in the same folder, then a rename).
template <class State>
void write_checkpoint_file(const std::string& path, const State& s) {
  io::write_file_atomically(path, [&](std::ostream& out) { write_checkpoint(out, s); });
}

/// Reads a SolverState checkpoint file. \throws InputError naming path
template <int Dim>
SolverState<Dim> read_checkpoint_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("cannot open the checkpoint", path);
  return read_checkpoint<Dim>(in, path);
}

/// 64-bit FNV-1a of `n` bytes, continuing from `h` (to tell whether a checkpoint belongs to a
/// scene: hash its file and mesh).
inline std::uint64_t fnv1a64(const void* data, std::size_t n,
                             std::uint64_t h = 0xcbf29ce484222325ULL) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 0x100000001b3ULL;
  }
  return h;
}

}  // namespace diffphd
