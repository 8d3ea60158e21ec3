// rotoscan: the command-line program. Everything happens in rotoscan::cli::Main (cli.cc).
#include <cstdlib>
#include <iostream>

#include "command.h"
#include "rotoscan/core/progress.h"

int main(int argc, char** argv) {
  // Open3D's Poisson (rotoscan mesh --method poisson) runs OpenMP threads that otherwise spin at every
  // barrier and burn the cores whenever anything else runs; passive waiting must be set before OpenMP
  // starts, so here, first. A user's own setting wins.
  setenv("OMP_WAIT_POLICY", "PASSIVE", /*overwrite=*/0);
  // Ctrl-C lets long work stop cleanly (core/progress.h); tests calling Main directly do not install it.
  rotoscan::InstallInterruptHandler();
  return rotoscan::cli::Main(argc, argv, std::cout, std::cerr);
}
