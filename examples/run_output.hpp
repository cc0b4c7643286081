#pragma once
// The files of `diffphd run --out DIR`, written so that a killed run leaves readable output and
// can be resumed (docs/reliability.md): stats.csv appended one whole frame per write,
// summary.json and the checkpoint replaced atomically (temporary file, then rename). The code
// here does not depend on the energy (examples/run_output.cpp): editing it rebuilds one
// translation unit, not every run_*.cpp.
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include <diffphd/io/scene.hpp>
#include <diffphd/solver/solver.hpp>
#include <diffphd/solver/state.hpp>

namespace diffphd::cli {

/// Command-line overrides of a scene's settings; unset = the scene's.
struct RunOptions {
  std::string out_dir;          ///< empty: write nothing
  std::optional<int> frames;    ///< --frames
  std::optional<double> contrast;  ///< --contrast (applied by load_scene; recorded for --resume)
  std::optional<int> anderson;  ///< --anderson
  std::optional<double> eps_rel;
  std::optional<int> max_iterations;
  std::optional<io::Routing> routing;
  std::optional<GateScale> gate;  ///< --gate
  std::optional<SolverMethod> method;  ///< --method
  std::optional<VolumeWeight> volume_weight;  ///< --volume-weight
  bool write_frames = true;       ///< VTU/PVD and OBJ per frame (stats are always written)
  bool progress = true;           ///< progress bar on a terminal
  int checkpoint_every = 10;      ///< --checkpoint-every (frames; 0: none)
  bool resume = false;            ///< --resume: continue the run in out_dir from its checkpoint
  /// Hidden --stop-after-frame K (tests): std::_Exit(137) once frame K's files are written,
  /// as if the run were killed there.
  std::optional<int> stop_after_frame;
};

/// Running totals of a run (summary.json). The checkpoint carries them, so the summary of a
/// resumed run covers the whole run.
struct RunTotals {
  long steps = 0, converged_steps = 0, iter_sum = 0, inner_sum = 0;
  int iter_max = 0, converged_frames = 0, aa_resets = 0;
  double seconds = 0, min_j = std::numeric_limits<double>::infinity();
  std::vector<double> step_seconds;
  std::string method_used;
  // Contact: worst over steps, and the largest fraction of vertices in contact.
  double worst_pen = 0, worst_compl = 0, worst_cone = -std::numeric_limits<double>::infinity();
  double max_fraction = 0, active_sum = 0;
  long redetections = 0, ncp_unconverged = 0, ncp_stalled = 0;
  std::vector<double> frame_times;  ///< time of every frame written (frame 0 included)
};

/// The totals as JSON (exact doubles) and back, for the checkpoint.
nlohmann::json totals_json(const RunTotals& t);
RunTotals totals_from_json(const nlohmann::json& j);

/// The summary: `info` (what does not change during the run) with the totals merged in.
/// `frames_done` frames are complete; `complete` is false until the run has ended.
nlohmann::json run_summary(nlohmann::json info, const RunTotals& t, bool contact,
                           const std::string& failure, int frames_done, bool complete);

/// The header line of stats.csv (with the contact columns when `contact`).
std::string stats_header(bool contact);

/// The --resume check: same scene (hash), same options. Throws InputError naming what differs.
void check_resume(const nlohmann::json& meta, std::uint64_t scene_hash, const RunOptions& opt,
                  const std::string& checkpoint_path);

/// FNV-1a of the scene file's bytes, then of the mesh (rest positions and elements).
std::uint64_t scene_hash(const std::string& scene_file, const void* positions,
                         std::size_t position_bytes, const void* elements,
                         std::size_t element_bytes);

/// The binary checkpoint of a SceneState (include/diffphd/solver/checkpoint.hpp).
std::string encode_state(const SceneState<2>& s);
std::string encode_state(const SceneState<3>& s);
void decode_state(const std::string& bytes, const std::string& what, SceneState<2>& out);
void decode_state(const std::string& bytes, const std::string& what, SceneState<3>& out);

/// The files of `--out DIR` other than the frames: stats.csv, summary.json, checkpoint.bin.
class RunFiles {
 public:
  /// Creates DIR and DIR/frames.
  explicit RunFiles(std::string dir);
  ~RunFiles();
  RunFiles(const RunFiles&) = delete;
  RunFiles& operator=(const RunFiles&) = delete;

  const std::string& dir() const { return dir_; }
  std::string frames_dir() const;
  std::string checkpoint_path() const;

  /// A new run: stats.csv holds the header only, and an old checkpoint is removed (it belongs
  /// to another run).
  void start(const std::string& header);
  /// A resumed run: stats.csv cut back to `bytes` (its size at the checkpoint).
  void resume_stats(std::uintmax_t bytes);
  /// Appends `rows` (whole lines) to stats.csv in one write.
  void append_stats(const std::string& rows);
  /// Size of stats.csv after the last append.
  std::uintmax_t stats_bytes() const { return stats_bytes_; }

  /// summary.json, atomically.
  void write_summary(const nlohmann::json& j) const;
  /// checkpoint.bin, atomically: "DPHDRUN1", u64 n, n bytes of JSON `meta`, then `state`.
  void write_checkpoint(const nlohmann::json& meta, const std::string& state) const;
  /// Reads checkpoint.bin: its meta, and the state bytes into `state`. Throws InputError when
  /// there is none or it is damaged.
  nlohmann::json read_checkpoint(std::string& state) const;

 private:
  std::string dir_;
  int fd_ = -1;
  std::uintmax_t stats_bytes_ = 0;
  void open_stats();
};

/// An output file written atomically by a writer that takes a path (write_surface_obj, ...):
/// write(tmp), then rename onto `path`.
template <class Write>
void write_atomically(const std::string& path, Write&& write);

/// The options recorded in the checkpoint and compared on --resume.
nlohmann::json run_options_json(const RunOptions& opt);

}  // namespace diffphd::cli

#include <diffphd/io/atomic_file.hpp>

template <class Write>
void diffphd::cli::write_atomically(const std::string& path, Write&& write) {
  write(io::temporary_path(path));
  io::replace_file(io::temporary_path(path), path);
}
