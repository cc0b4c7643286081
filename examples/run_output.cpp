// The output files of `diffphd run` (see run_output.hpp).
#include "run_output.hpp"

#include <fcntl.h>
#include <omp.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <diffphd/io/atomic_file.hpp>
#include <diffphd/linalg/blas_threads.hpp>
#include <diffphd/solver/checkpoint.hpp>

#include "file_bytes.hpp"

namespace diffphd::cli {

namespace fs = std::filesystem;
using json = nlohmann::json;

namespace {

constexpr char kRunMagic[8] = {'D', 'P', 'H', 'D', 'R', 'U', 'N', '1'};

/// JSON has no infinities: null stands for -inf (worst_cone before any contact) and +inf.
json finite_or_null(double x) { return std::isfinite(x) ? json(x) : json(nullptr); }
double from_json_or(const json& j, double fallback) {
  return j.is_null() ? fallback : j.get<double>();
}

/// The command-line flag of each key of run_options_json().
const char* option_flag(const std::string& key) {
  static const std::pair<const char*, const char*> flags[] = {
      {"contrast", "--contrast"},     {"anderson", "--anderson"},
      {"eps_rel", "--eps-rel"},       {"max_iterations", "--max-iterations"},
      {"routing", "--routing"},       {"gate", "--gate"},
      {"method", "--method"},         {"volume_weight", "--volume-weight"},
      {"write_frames", "--no-frames"}};
  for (const auto& [k, f] : flags)
    if (key == k) return f;
  return "an option";
}

std::string shown(const json& v) { return v.is_null() ? "unset (the scene's)" : v.dump(); }

template <int Dim>
std::string encode(const SceneState<Dim>& s) {
  std::ostringstream out(std::ios::binary);
  write_checkpoint(out, s);
  return out.str();
}

template <int Dim>
void decode(const std::string& bytes, const std::string& what, SceneState<Dim>& out) {
  std::istringstream in(bytes, std::ios::binary);
  out = read_scene_checkpoint<Dim>(in, what);
}

}  // namespace

json totals_json(const RunTotals& t) {
  return json{{"steps", t.steps},
              {"converged_steps", t.converged_steps},
              {"iter_sum", t.iter_sum},
              {"inner_sum", t.inner_sum},
              {"iter_max", t.iter_max},
              {"converged_frames", t.converged_frames},
              {"aa_resets", t.aa_resets},
              {"seconds", t.seconds},
              {"min_j", finite_or_null(t.min_j)},
              {"step_seconds", t.step_seconds},
              {"method_used", t.method_used},
              {"worst_pen", t.worst_pen},
              {"worst_compl", t.worst_compl},
              {"worst_cone", finite_or_null(t.worst_cone)},
              {"max_fraction", t.max_fraction},
              {"active_sum", t.active_sum},
              {"redetections", t.redetections},
              {"ncp_unconverged", t.ncp_unconverged},
              {"ncp_stalled", t.ncp_stalled},
              {"frame_times", t.frame_times}};
}

RunTotals totals_from_json(const json& j) {
  RunTotals t;
  t.steps = j.at("steps");
  t.converged_steps = j.at("converged_steps");
  t.iter_sum = j.at("iter_sum");
  t.inner_sum = j.at("inner_sum");
  t.iter_max = j.at("iter_max");
  t.converged_frames = j.at("converged_frames");
  t.aa_resets = j.at("aa_resets");
  t.seconds = j.at("seconds");
  t.min_j = from_json_or(j.at("min_j"), std::numeric_limits<double>::infinity());
  t.step_seconds = j.at("step_seconds").get<std::vector<double>>();
  t.method_used = j.at("method_used");
  t.worst_pen = j.at("worst_pen");
  t.worst_compl = j.at("worst_compl");
  t.worst_cone = from_json_or(j.at("worst_cone"), -std::numeric_limits<double>::infinity());
  t.max_fraction = j.at("max_fraction");
  t.active_sum = j.at("active_sum");
  t.redetections = j.at("redetections");
  t.ncp_unconverged = j.at("ncp_unconverged");
  t.ncp_stalled = j.value("ncp_stalled", 0L);  // absent in checkpoints before 2026-12-07
  t.frame_times = j.at("frame_times").get<std::vector<double>>();
  return t;
}

std::string encode_state(const SceneState<2>& s) { return encode(s); }
std::string encode_state(const SceneState<3>& s) { return encode(s); }
void decode_state(const std::string& b, const std::string& what, SceneState<2>& out) {
  decode(b, what, out);
}
void decode_state(const std::string& b, const std::string& what, SceneState<3>& out) {
  decode(b, what, out);
}

json run_options_json(const RunOptions& o) {
  json j;
  auto put = [&](const char* key, const auto& v) {
    if (v)
      j[key] = *v;
    else
      j[key] = nullptr;
  };
  put("contrast", o.contrast);
  put("anderson", o.anderson);
  put("eps_rel", o.eps_rel);
  put("max_iterations", o.max_iterations);
  j["routing"] = o.routing ? json(io::to_string(*o.routing)) : json(nullptr);
  j["gate"] = o.gate ? json(to_string(*o.gate)) : json(nullptr);
  j["method"] = o.method ? json(to_string(*o.method)) : json(nullptr);
  j["volume_weight"] = o.volume_weight ? json(to_string(*o.volume_weight)) : json(nullptr);
  j["write_frames"] = o.write_frames;
  return j;
}

json run_summary(json j, const RunTotals& t, bool contact, const std::string& failure,
                 int frames_done, bool complete) {
  // The median by nth_element: the summary is rewritten every frame (O(steps) each time).
  std::vector<double> sorted = t.step_seconds;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  j["steps"] = t.steps;
  j["frames_done"] = frames_done;
  j["complete"] = complete;
  j["converged_frames"] = t.converged_frames;
  j["converged_steps"] = t.converged_steps;
  j["mean_iterations"] = t.steps ? double(t.iter_sum) / t.steps : 0.0;
  j["max_iterations"] = t.iter_max;
  j["aa_resets"] = t.aa_resets;
  j["method"] = t.method_used;
  j["mean_inner_iterations"] = t.steps ? double(t.inner_sum) / t.steps : 0.0;
  j["seconds_per_step"] = t.steps ? t.seconds / t.steps : 0.0;
  j["median_seconds_per_step"] = sorted.empty() ? 0.0 : sorted[sorted.size() / 2];
  j["min_jacobian"] = t.min_j;
  j["contact"] = contact;
  if (contact) {
    j["worst_penetration"] = t.worst_pen;
    j["max_complementarity"] = t.worst_compl;
    j["max_cone_violation"] = std::isfinite(t.worst_cone) ? t.worst_cone : 0.0;
    j["max_contact_fraction"] = t.max_fraction;
    j["mean_active_contacts"] = t.steps ? t.active_sum / t.steps : 0.0;
    j["redetections"] = t.redetections;
    j["ncp_unconverged_iterations"] = t.ncp_unconverged;
    j["ncp_stalled_iterations"] = t.ncp_stalled;
  }
  j["blas_threads"] = blas_threads();  // -1: the BLAS is not OpenBLAS
  j["openmp_threads"] = omp_get_max_threads();
  // Peak resident memory of this process so far (getrusage; Linux reports KiB). A resumed run
  // reports its own process only.
  rusage ru{};
  j["peak_rss_kib"] = getrusage(RUSAGE_SELF, &ru) == 0 ? static_cast<long>(ru.ru_maxrss) : -1L;
  j["status"] = failure.empty() ? "ok" : "non-finite";
  if (!failure.empty()) j["error"] = failure;
  return j;
}

std::string stats_header(bool contact) {
  std::string h =
      "frame,step,time,iterations,primal_ratio,dual_ratio,converged,status,aa_resets,"
      "seconds,kinetic_energy,min_jacobian,max_displacement,method,inner_iterations,"
      "gradient_ratio,projected_elements";
  if (contact)
    h += ",contact_points,contact_active,contact_sliding,contact_fraction,worst_penetration,"
         "complementarity,cone_violation,w_off_diagonal_ratio,ncp_iterations,ncp_ldlt,ncp_lu,"
         "ncp_krylov,ncp_krylov_iterations,ncp_unconverged,ncp_stalled,redetections,"
         "seconds_detection,"
         "seconds_delassus,seconds_ncp";
  return h + "\n";
}

std::uint64_t scene_hash(const std::string& scene_file, const void* positions,
                         std::size_t position_bytes, const void* elements,
                         std::size_t element_bytes) {
  const std::string text = read_file_bytes(scene_file).value_or(std::string());
  std::uint64_t h = fnv1a64(text.data(), text.size());
  h = fnv1a64(positions, position_bytes, h);
  return fnv1a64(elements, element_bytes, h);
}

void check_resume(const json& meta, std::uint64_t hash, const RunOptions& opt,
                  const std::string& path) {
  const std::string prefix = "--resume " + opt.out_dir + ": ";
  if (meta.at("scene_hash").get<std::string>() != std::to_string(hash))
    throw InputError(prefix + "the checkpoint belongs to another scene (" +
                         meta.at("scene").get<std::string>() +
                         ", or its mesh, as it was then); resume with that scene or start anew "
                         "without --resume",
                     path);
  const json now = run_options_json(opt), then = meta.at("options");
  for (auto it = then.begin(); it != then.end(); ++it) {
    const json& v = now.contains(it.key()) ? now.at(it.key()) : json(nullptr);
    if (v != it.value())
      throw InputError(prefix + "the run was started with " + option_flag(it.key()) + " " +
                           shown(it.value()) + ", this command has " + shown(v) +
                           "; resume with the same options",
                       path);
  }
}

// ---- RunFiles --------------------------------------------------------------------------------

RunFiles::RunFiles(std::string dir) : dir_(std::move(dir)) {
  std::error_code ec;
  fs::create_directories(fs::path(dir_) / "frames", ec);
  if (ec) throw InputError("cannot create the output directory: " + ec.message(), dir_);
}

RunFiles::~RunFiles() {
  if (fd_ >= 0) ::close(fd_);
}

std::string RunFiles::frames_dir() const { return (fs::path(dir_) / "frames").string(); }
std::string RunFiles::checkpoint_path() const { return (fs::path(dir_) / "checkpoint.bin").string(); }

void RunFiles::open_stats() {
  const std::string path = (fs::path(dir_) / "stats.csv").string();
  fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (fd_ < 0) throw InputError(std::string("cannot write: ") + std::strerror(errno), path);
}

void RunFiles::start(const std::string& header) {
  std::error_code ec;
  fs::remove(checkpoint_path(), ec);
  io::write_file_atomically((fs::path(dir_) / "stats.csv").string(),
                            [&](std::ostream& out) { out << header; });
  stats_bytes_ = header.size();
  open_stats();
}

void RunFiles::resume_stats(std::uintmax_t bytes) {
  const std::string path = (fs::path(dir_) / "stats.csv").string();
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec || size < bytes)
    throw InputError("--resume " + dir_ + ": stats.csv is " +
                         (ec ? "missing" : "shorter than at the checkpoint") +
                         "; the folder was changed since",
                     path);
  fs::resize_file(path, bytes);
  stats_bytes_ = bytes;
  open_stats();
}

void RunFiles::append_stats(const std::string& rows) {
  // One write(2) per frame: a killed run leaves whole lines (a regular file's write is not cut
  // short by a signal).
  const char* p = rows.data();
  std::size_t left = rows.size();
  while (left > 0) {
    const ssize_t n = ::write(fd_, p, left);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0)
      throw InputError(std::string("write failed: ") + std::strerror(errno),
                       (fs::path(dir_) / "stats.csv").string());
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  stats_bytes_ += rows.size();
}

void RunFiles::write_summary(const json& j) const {
  io::write_file_atomically((fs::path(dir_) / "summary.json").string(),
                            [&](std::ostream& out) { out << j.dump(2) << "\n"; });
}

void RunFiles::write_checkpoint(const json& meta, const std::string& state) const {
  const std::string text = meta.dump();
  io::write_file_atomically(checkpoint_path(), [&](std::ostream& out) {
    out.write(kRunMagic, sizeof kRunMagic);
    const std::uint64_t n = text.size();
    out.write(reinterpret_cast<const char*>(&n), sizeof n);
    out << text << state;
  });
}

json RunFiles::read_checkpoint(std::string& state) const {
  const std::string path = checkpoint_path();
  const std::optional<std::string> file = read_file_bytes(path);
  if (!file)
    throw InputError("--resume " + dir_ +
                     ": no checkpoint.bin (the run was not started with --out there, or was "
                     "stopped before its first checkpoint: run it again without --resume)");
  const std::string& bytes = *file;
  std::uint64_t n = 0;
  if (bytes.size() < sizeof kRunMagic + sizeof n ||
      bytes.compare(0, sizeof kRunMagic, kRunMagic, sizeof kRunMagic) != 0)
    throw InputError("not a diffphd run checkpoint", path);
  std::memcpy(&n, bytes.data() + sizeof kRunMagic, sizeof n);
  const std::size_t head = sizeof kRunMagic + sizeof n;
  if (n > bytes.size() - head) throw InputError("damaged checkpoint (truncated)", path);
  json meta;
  try {
    meta = json::parse(bytes.substr(head, n));
    totals_from_json(meta.at("totals"));
  } catch (const json::exception& e) {
    throw InputError(std::string("damaged checkpoint: ") + e.what(), path);
  }
  state = bytes.substr(head + n);
  return meta;
}

}  // namespace diffphd::cli
