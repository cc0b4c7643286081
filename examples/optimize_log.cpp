// The evaluation log of `diffphd optimize` and its reading for --resume (optimize_log.hpp).
#include "optimize_log.hpp"

#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>

#include <diffphd/core/errors.hpp>
#include <diffphd/solver/checkpoint.hpp>

#include "file_bytes.hpp"

namespace diffphd::cli {

using json = nlohmann::json;

namespace {
// j[key] as a vector; n < 0: any length (then set to it), else exactly n entries.
VectorX vector_of(const json& j, const char* key, long& n, const std::string& path, long line) {
  const json& a = j.at(key);
  if (!a.is_array() || a.empty() || (n >= 0 && static_cast<long>(a.size()) != n))
    throw InputError(std::string("\"") + key + "\" must be an array of " +
                         (n >= 0 ? std::to_string(n) + " numbers (as on line 1)" : "numbers"),
                     path, line);
  n = static_cast<long>(a.size());
  VectorX v(n);
  for (long i = 0; i < n; ++i) {
    if (!a[static_cast<std::size_t>(i)].is_number())
      throw InputError(std::string("\"") + key + "\"[" + std::to_string(i) + "] is not a number",
                       path, line);
    v[i] = a[static_cast<std::size_t>(i)].get<double>();
  }
  return v;
}
}  // namespace

std::uint64_t task_hash(const optim::TaskSpec& task) {
  const std::string t = read_file_bytes(task.file).value_or(std::string());
  const std::string s = read_file_bytes(task.scene.file).value_or(std::string());
  return fnv1a64(s.data(), s.size(), fnv1a64(t.data(), t.size()));
}

EvaluationLog read_evaluation_log(const std::string& path, std::uint64_t hash) {
  const std::optional<std::string> file = read_file_bytes(path);
  if (!file) throw InputError("--resume: no evaluation log to resume from", path);
  const std::string& text = *file;
  EvaluationLog log;
  std::size_t start = 0;
  long line = 0, n = -1;
  while (start < text.size()) {
    const std::size_t end = text.find('\n', start);
    if (end == std::string::npos) {  // killed while this line was being written
      log.dropped_partial_line = true;
      break;
    }
    ++line;
    json j;
    try {
      j = json::parse(text.begin() + static_cast<std::ptrdiff_t>(start),
                      text.begin() + static_cast<std::ptrdiff_t>(end));
    } catch (const json::exception& e) {
      throw InputError(std::string("invalid JSON: ") + e.what(), path, line);
    }
    try {
      if (!j.contains("grad") || !j.contains("task_hash"))
        throw InputError(
            "the line has no \"grad\" or \"task_hash\" (a log written by an older diffphd): it "
            "cannot be resumed; start anew without --resume",
            path, line);
      if (j.at("task_hash").get<std::string>() != std::to_string(hash))
        throw InputError(
            "the log belongs to another task (its task or scene file has changed since); resume "
            "with the task as it was or start anew without --resume",
            path, line);
      optim::Evaluation e;
      e.index = j.at("evaluation").get<int>();
      if (e.index != line - 1)
        throw InputError("evaluation " + std::to_string(e.index) + " where " +
                             std::to_string(line - 1) + " was expected",
                         path, line);
      e.loss = j.at("loss").get<double>();
      e.grad_norm = j.at("grad_norm").get<double>();
      e.seconds = j.at("seconds").get<double>();
      e.x = vector_of(j, "x", n, path, line);
      e.grad = vector_of(j, "grad", n, path, line);
      log.evaluations.push_back(std::move(e));
    } catch (const json::exception& e) {
      throw InputError(std::string("not an evaluation: ") + e.what(), path, line);
    }
    start = end + 1;
    log.bytes = start;
  }
  return log;
}

void write_evaluation(std::ofstream& out, const optim::Evaluation& e, std::uint64_t hash) {
  // nlohmann writes the shortest decimal that reads back to the same double, so x, loss and
  // grad round-trip exactly (what --resume's replay needs).
  out << json{{"evaluation", e.index},
              {"loss", e.loss},
              {"grad_norm", e.grad_norm},
              {"seconds", e.seconds},
              {"x", std::vector<double>(e.x.data(), e.x.data() + e.x.size())},
              {"grad", std::vector<double>(e.grad.data(), e.grad.data() + e.grad.size())},
              {"task_hash", std::to_string(hash)}}
             .dump()
      << '\n';
  out.flush();
}

}  // namespace diffphd::cli
