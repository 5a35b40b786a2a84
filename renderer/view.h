#pragma once
// `isotrace view SCENE.json`: a small HTTP server (cpp-httplib) with one page (renderer/
// view_page.h, compiled in) to explore a scene live: iso values, colours, the integrator and
// the camera change while the image refines progressively. Frames reach the page as
// server-sent events (JPEG in a data URL). It serves only its page, its state, its frames and
// Save; never a file named by a request.
#include <memory>
#include <string>

#include "scene/scene.h"

namespace iso {

struct ViewOptions {
  std::string host = "127.0.0.1";
  int port = 8765;   // 0: any free port
  int width = 0;     // 0: 480 wide, the scene's aspect
  int height = 0;
  int threads = 0;   // 0: all cores
  SceneOverrides overrides;  // --set / --iso: applied to the scene's JSON the view starts from
};

class ViewSession;

// The server of one scene. Loading errors are InputErrors from the constructor.
class ViewServer {
 public:
  ViewServer(const std::string& scenePath, const ViewOptions& options);
  ~ViewServer();
  // Binds (port 0: any free one) and returns the port; then serve() blocks until stop().
  int bind();
  void serve();
  // From any thread: ends serve() within a second (open event streams included).
  void stop();
  std::string url() const;

 private:
  ViewOptions m_options;
  int m_port = 0;
  std::unique_ptr<ViewSession> m_session;
  struct Http;
  std::unique_ptr<Http> m_http;
};

// The command: prints the URL on the first line of stdout, serves until SIGINT/SIGTERM, exit 0.
int runView(const std::string& scenePath, const ViewOptions& options);

}  // namespace iso
