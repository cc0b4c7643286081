#pragma once
/// \file vtk.hpp
/// \brief ParaView output: write_vtu (one VTK XML UnstructuredGrid, ASCII) and PvdWriter (a
/// time series of .vtu files listed in a .pvd collection rewritten after every frame; both
/// written atomically: a temporary file, then a rename).

#include <cstdio>
#include <filesystem>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "../core/errors.hpp"
#include "../core/mesh.hpp"
#include "atomic_file.hpp"
#include "detail/text_reader.hpp"

namespace diffphd::io {

/// Per-vertex fields: name -> #V by k matrix (k = 1 scalar, k = Dim vector, any k allowed).
using PointData = std::map<std::string, Eigen::MatrixXd>;
/// Per-element fields: name -> #E vector.
using CellData = std::map<std::string, Eigen::VectorXd>;

/// \brief Writes a mesh in deformed positions as a VTK XML UnstructuredGrid (.vtu, ASCII).
///
/// 2D meshes are written with z = 0 and cell type VTK_TRIANGLE (5), tetrahedra as VTK_TETRA
/// (10). In 2D, 2-column point data are padded with a zero z so ParaView treats them as vectors.
///
/// \param[in] path  output file
/// \param[in] mesh  #V vertices, #E elements
/// \param[in] x  #V by Dim deformed positions
/// \param[in] point_data  name -> #V by k matrix
/// \param[in] cell_data  name -> #E vector
/// \throws InputError naming path when it cannot be written, or naming the field whose shape is
///   wrong
template <int Dim, typename DerivedX>
void write_vtu(const std::string& path, const SimplicialMesh<Dim>& mesh,
               const Eigen::MatrixBase<DerivedX>& x, const PointData& point_data = {},
               const CellData& cell_data = {}) {
  const Index nv = mesh.num_vertices(), ne = mesh.num_elements();
  if (x.rows() != nv || x.cols() != Dim)
    throw InputError("write_vtu: x is " + std::to_string(x.rows()) + " by " +
                         std::to_string(x.cols()) + ", expected " + std::to_string(nv) + " by " +
                         std::to_string(Dim),
                     path);
  for (const auto& [name, m] : point_data)
    if (m.rows() != nv || m.cols() < 1)
      throw InputError("write_vtu: point data '" + name + "' has " + std::to_string(m.rows()) +
                           " rows, expected " + std::to_string(nv),
                       path);
  for (const auto& [name, v] : cell_data)
    if (v.size() != ne)
      throw InputError("write_vtu: cell data '" + name + "' has " + std::to_string(v.size()) +
                           " entries, expected " + std::to_string(ne),
                       path);

  auto out = detail::open_for_writing(path);
  out << "<?xml version=\"1.0\"?>\n"
         "<VTKFile type=\"UnstructuredGrid\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
         "<UnstructuredGrid>\n"
      << "<Piece NumberOfPoints=\"" << nv << "\" NumberOfCells=\"" << ne << "\">\n";
  out << "<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n";
  for (Index v = 0; v < nv; ++v)
    out << x(v, 0) << ' ' << x(v, 1) << ' ' << (Dim == 3 ? double(x(v, Dim - 1)) : 0.0) << '\n';
  out << "</DataArray>\n</Points>\n<Cells>\n"
         "<DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">\n";
  const auto& T = mesh.elements();
  for (Index e = 0; e < ne; ++e) {
    for (int a = 0; a <= Dim; ++a) out << (a ? " " : "") << T(e, a);
    out << '\n';
  }
  out << "</DataArray>\n<DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">\n";
  for (Index e = 0; e < ne; ++e) out << (e + 1) * (Dim + 1) << (e % 16 == 15 ? '\n' : ' ');
  out << "\n</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n";
  for (Index e = 0; e < ne; ++e) out << (Dim == 3 ? 10 : 5) << (e % 32 == 31 ? '\n' : ' ');
  out << "\n</DataArray>\n</Cells>\n";
  if (!point_data.empty()) {
    out << "<PointData>\n";
    for (const auto& [name, m] : point_data) {
      const bool pad = Dim == 2 && m.cols() == 2;
      out << "<DataArray type=\"Float64\" Name=\"" << name << "\" NumberOfComponents=\""
          << (pad ? 3 : m.cols()) << "\" format=\"ascii\">\n";
      for (Index v = 0; v < nv; ++v) {
        for (Eigen::Index k = 0; k < m.cols(); ++k) out << (k ? " " : "") << m(v, k);
        out << (pad ? " 0\n" : "\n");
      }
      out << "</DataArray>\n";
    }
    out << "</PointData>\n";
  }
  if (!cell_data.empty()) {
    out << "<CellData>\n";
    for (const auto& [name, c] : cell_data) {
      out << "<DataArray type=\"Float64\" Name=\"" << name << "\" format=\"ascii\">\n";
      for (Index e = 0; e < ne; ++e) out << c[e] << '\n';
      out << "</DataArray>\n";
    }
    out << "</CellData>\n";
  }
  out << "</Piece>\n</UnstructuredGrid>\n</VTKFile>\n";
  detail::finish_writing(out, path);
}

/// \brief A ParaView time series: one dir/basename_NNNNNN.vtu per frame and dir/basename.pvd
/// listing the frames written so far (rewritten after every frame, so an interrupted run can
/// still be opened).
///
/// \code
/// diffphd::io::PvdWriter pvd("out", "bar");
/// for (int step = 0; step < 100; ++step) {
///   solver.step();
///   pvd.add_frame(step * dt, mesh, solver.positions(), {{"velocity", solver.velocities()}});
/// }  // out/bar.pvd, out/bar_000000.vtu ... out/bar_000099.vtu
/// \endcode
class PvdWriter {
 public:
  /// \param[in] dir  output directory (created if missing)
  /// \param[in] basename  file name prefix of the .pvd and .vtu files
  /// \throws InputError naming dir when it cannot be created
  PvdWriter(std::string dir, std::string basename)
      : dir_(std::move(dir)), basename_(std::move(basename)) {
    std::error_code ec;
    std::filesystem::create_directories(dir_, ec);
    if (ec || !std::filesystem::is_directory(dir_))
      throw InputError("cannot create the output directory: " + ec.message(), dir_);
  }

  /// Writes frame number num_frames() at `time` (see write_vtu for the arguments; the .vtu is
  /// written to a temporary file renamed into place) and rewrites the .pvd collection.
  template <int Dim, typename DerivedX>
  void add_frame(double time, const SimplicialMesh<Dim>& mesh, const Eigen::MatrixBase<DerivedX>& x,
                 const PointData& point_data = {}, const CellData& cell_data = {}) {
    const std::string name = frame_name(static_cast<int>(frames_.size()));
    const std::string path = dir_ + "/" + name;
    write_vtu(temporary_path(path), mesh, x, point_data, cell_data);
    replace_file(temporary_path(path), path);
    frames_.emplace_back(time, name);
    write_collection();
  }

  /// Continues an earlier series in the same folder (a resumed run): frames 0 ..
  /// times.size() - 1 are taken as written at `times` (their .vtu files are not touched), later
  /// frames are dropped from the collection, which is rewritten; the next add_frame() writes
  /// frame times.size().
  void resume(const std::vector<double>& times) {
    frames_.clear();
    for (size_t i = 0; i < times.size(); ++i)
      frames_.emplace_back(times[i], frame_name(static_cast<int>(i)));
    write_collection();
  }

  int num_frames() const { return static_cast<int>(frames_.size()); }
  /// The time of every frame written (or resumed) so far.
  std::vector<double> frame_times() const {
    std::vector<double> t;
    for (const auto& f : frames_) t.push_back(f.first);
    return t;
  }
  /// dir/basename.pvd
  std::string pvd_path() const { return dir_ + "/" + basename_ + ".pvd"; }
  /// dir/basename_NNNNNN.vtu of frame i
  std::string frame_path(int i) const { return dir_ + "/" + frame_name(i); }

 private:
  std::string frame_name(int i) const {
    char buf[16];
    std::snprintf(buf, sizeof buf, "_%06d.vtu", i);
    return basename_ + buf;
  }
  void write_collection() const {
    const std::string path = pvd_path(), tmp = temporary_path(path);
    {
      auto out = detail::open_for_writing(tmp);
      out << "<?xml version=\"1.0\"?>\n"
             "<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
             "<Collection>\n";
      for (const auto& [time, name] : frames_)
        out << "<DataSet timestep=\"" << time << "\" group=\"\" part=\"0\" file=\"" << name
            << "\"/>\n";
      out << "</Collection>\n</VTKFile>\n";
      detail::finish_writing(out, tmp);
    }
    replace_file(tmp, path);  // atomic: a reader never sees a half-written file
  }

  std::string dir_, basename_;
  std::vector<std::pair<double, std::string>> frames_;
};

}  // namespace diffphd::io
