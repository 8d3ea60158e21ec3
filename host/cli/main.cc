// rotoscan: the command-line program. Everything happens in rotoscan::cli::Main (cli.cc).
#include <iostream>

#include "command.h"
#include "rotoscan/core/progress.h"

int main(int argc, char** argv) {
  // Ctrl-C lets long work stop cleanly (core/progress.h); tests calling Main directly do not install it.
  rotoscan::InstallInterruptHandler();
  return rotoscan::cli::Main(argc, argv, std::cout, std::cerr);
}
