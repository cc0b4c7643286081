// Explicit instantiation of the backward-pass commands for one energy (its own translation unit).
#include "adjoint_cli.hpp"

DIFFPHD_CLI_DEFINE_ADJOINT(diffphd::Corotated)
