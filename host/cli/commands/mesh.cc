// rotoscan mesh: Mesh a colored point cloud (Poisson) and draw a preview picture
#include <ostream>

#include "command.h"

namespace rotoscan::cli {

void RegisterMesh(CLI::App& app, const Context& context, int* exit_code) {
  CLI::App* sub =
      app.add_subcommand("mesh", "Mesh a colored point cloud (Poisson) and draw a preview picture");
  static std::string cloud, out;
  sub->add_option("cloud", cloud, "input point cloud (PLY)");
  sub->add_option("--out", out, "output mesh (PLY, OBJ or STL)");
  sub->callback([&context, exit_code] { *exit_code = NotBuilt(context, "mesh", "meshing (a later issue)"); });
}

}  // namespace rotoscan::cli
