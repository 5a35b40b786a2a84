// `isotrace view`: the scene live in the browser (the server and its page: view.cpp).
#include <CLI/CLI.hpp>

#include <memory>

#include "renderer/commands.h"
#include "renderer/distributed.h"
#include "renderer/view.h"
#include "volume/input_error.h"

namespace iso {

Command addViewCommand(CLI::App& app) {
  struct Flags {
    std::string scene, resolution;
    ViewOptions options;
  };
  auto flags = std::make_shared<Flags>();
  CLI::App* cmd = app.add_subcommand("view", "explore a scene live in the browser: iso values, colours, integrator, camera");
  cmd->add_option("scene", flags->scene, "scene file (JSON)")->required();
  cmd->add_option("--port", flags->options.port, "port to listen on (default 8765; 0: any free port)")->check(CLI::Range(0, 65535));
  cmd->add_option("--host", flags->options.host, "address to listen on (default 127.0.0.1: this machine only)");
  cmd->add_option("--resolution", flags->resolution, "image size WIDTHxHEIGHT (default 480 wide, the scene's aspect)");
  cmd->add_option("--threads", flags->options.threads, "worker threads (0: all cores, at most 1024)")->check(CLI::Range(0, 1024));
  addSceneOverrides(cmd, flags->options.overrides);
  return {cmd, [flags] {
            // One server, one process: under mpirun every rank would start its own on the port.
            // (A data-parallel scene is viewed whole in this process.)
            const LaunchedRanks ranks = launchedRanks();
            if (ranks.size > 1) {
              if (ranks.rank != 0) return 2;  // rank 0 alone says it
              throw InputError("view", "", "runs in one process: start it without mpirun (it was started as " +
                                               std::to_string(ranks.size) + " ranks)");
            }
            ViewOptions options = flags->options;
            if (!flags->resolution.empty()) {
              parseResolution(flags->resolution, options.width, options.height);
              if (double(options.width) * options.height > double(1 << 22))
                throw InputError("--resolution", "", "a live view holds at most 2^22 pixels (e.g. 2048x2048)");
            }
            return runView(flags->scene, options);
          }};
}

}  // namespace iso
