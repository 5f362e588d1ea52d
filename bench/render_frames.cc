// Instructions per rendered frame (issue 5), the figure that does not vary with this machine's
// load: renders one frame of a benchmark scene (bench/render_scenes.h) to pay the one-time costs,
// then N frames in RenderFrames(), and prints a checksum of the last frame (the same bytes before
// and after a speed-up) and its edge pixels. Count with
//   valgrind --tool=callgrind --toggle-collect='*RenderFrames*' build/bench/render_frames soccer 3
// and divide the total by N.
// Usage: render_frames SCENE [FRAMES=3] [EFFECTS=0|1]; SCENE one of the names it lists.

#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "bench/render_scenes.h"

namespace kinevis::vision::render {

__attribute__((noinline)) void RenderFrames(Renderer& renderer, const Scene& scene,
                                            const ImageView8& view, int frames) {
  for (int f = 1; f <= frames; ++f) renderer.Render(scene, static_cast<uint64_t>(f), view);
}

}  // namespace kinevis::vision::render

int main(int argc, char** argv) {
  using namespace kinevis::vision::render;
  using kinevis::vision::ImageView8;
  const std::string name = argc > 1 ? argv[1] : "";
  const bench::BenchScene s = bench::MakeBenchScene(name);
  const int frames = argc > 2 ? std::atoi(argv[2]) : 3;
  const int effects = argc > 3 ? std::atoi(argv[3]) : 0;
  if (!s.scene || frames < 1 || (effects != 0 && effects != 1)) {
    std::fprintf(stderr, "usage: render_frames SCENE [FRAMES>=1] [EFFECTS=0|1]; SCENE is one of:");
    for (const std::string& n : bench::BenchSceneNames()) std::fprintf(stderr, " %s", n.c_str());
    std::fprintf(stderr, "\n");
    return 2;
  }
  Renderer renderer(*s.camera, bench::BenchOptions(effects != 0));
  const int width = s.camera->width(), height = s.camera->height();
  std::vector<uint8_t> pixels(static_cast<size_t>(width) * height);
  const ImageView8 view{pixels.data(), width, height, static_cast<size_t>(width)};
  renderer.Render(*s.scene, 0, view);
  RenderFrames(renderer, *s.scene, view, frames);
  uint64_t fnv = 0xcbf29ce484222325ULL;  // FNV-1a of the last frame
  for (const uint8_t b : pixels) fnv = (fnv ^ b) * 0x100000001b3ULL;
  std::printf("%s: %d frames after the first, last frame FNV-1a %016llx, %d edge pixels\n",
              name.c_str(), frames, static_cast<unsigned long long>(fnv),
              renderer.last_edge_pixels());
  return 0;
}
