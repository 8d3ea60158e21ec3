// rotoscan: the command-line program. Everything happens in rotoscan::cli::Main (cli.cc).
#include <iostream>

#include "command.h"

int main(int argc, char** argv) {
  return rotoscan::cli::Main(argc, argv, std::cout, std::cerr);
}
