#pragma once
// Video output (`-o out.mp4` or `.webm`): a sequence's frames, as PNG would show them (8-bit
// sRGB after exposure and tone mapping, legends below), piped as raw RGB into Debian's `ffmpeg`
// program, which encodes H.264 (MP4) or VP9 (WebM), 4:2:0, each side padded to an even count.
// The video is written to a temporary file beside its name and renamed when ffmpeg has finished:
// a failed or abandoned sequence leaves no partial video.
#include <sys/types.h>

#include <cstdint>
#include <string>
#include <vector>

namespace iso {

// Whether an output name asks for a video (.mp4, .webm).
bool isVideoName(const std::string& path);
// The ffmpeg program to run (ISOTRACE_FFMPEG, else `ffmpeg` on PATH); an InputError naming
// `what` (the flag) when there is none.
std::string findFfmpeg(const std::string& what);

class VideoWriter {
 public:
  // Starts ffmpeg for frames of width x height at `fps` frames per second. Errors (no ffmpeg, no
  // output folder) are InputErrors naming `path`.
  VideoWriter(const std::string& path, int width, int height, double fps);
  ~VideoWriter();  // unfinished: ffmpeg stopped, its temporary file removed
  VideoWriter(const VideoWriter&) = delete;
  VideoWriter& operator=(const VideoWriter&) = delete;

  // One frame: width x height x 3 bytes, row by row from the top.
  void add(const std::vector<uint8_t>& rgb);
  // Ends the stream, waits for ffmpeg and puts the video in place; an InputError with ffmpeg's
  // last words if it failed. `frames()` frames were written.
  void finish();
  int frames() const { return m_frames; }

 private:
  void stop();
  std::string m_path, m_temp;
  int m_width, m_height, m_frames = 0;
  pid_t m_pid = -1;
  int m_in = -1;           // ffmpeg's stdin
  std::string m_errFile;   // ffmpeg's stderr, for the message when it fails
  bool m_finished = false;
};

}  // namespace iso
