#pragma once
// A progress bar for long work: drawn on stderr only when stderr is a terminal.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>

class ProgressBar {
 public:
  ProgressBar(std::string label, long total, bool enabled = true)
      : label_(std::move(label)),
        total_(total),
        enabled_(enabled && isatty(fileno(stderr))),
        start_(std::chrono::steady_clock::now()) {}
  void tick(long n = 1) {
    done_ += n;
    if (enabled_) draw();
  }
  void finish() {
    if (enabled_) std::fprintf(stderr, "\n");
    enabled_ = false;
  }
  ~ProgressBar() { finish(); }

 private:
  void draw() const {
    const double frac = total_ > 0 ? double(done_) / total_ : 1.0;
    const double s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    const int width = 30, fill = static_cast<int>(frac * width);
    std::fprintf(stderr, "\r%s [%.*s%*s] %ld/%ld %.1fs eta %.1fs", label_.c_str(), fill,
                 "##############################", width - fill, "", done_, total_, s,
                 frac > 0 ? s * (1 - frac) / frac : 0.0);
    std::fflush(stderr);
  }
  std::string label_;
  long total_, done_ = 0;
  bool enabled_;
  std::chrono::steady_clock::time_point start_;
};
