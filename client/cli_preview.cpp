#include "client/cli_preview.h"

#include "client/cli_jobs.h"
#include "client/exit_codes.h"
#include "client/particle_files.h"
#include "core/util/text.h"

namespace surfacer::client {

CLI::App* add_preview_command(CLI::App& app, PreviewFlags& flags) {
  CLI::App* preview = app.add_subcommand(
      "preview", "Render shaded PNG pictures of frame files (no server needed), one camera for the whole sequence");
  preview->add_option("frames", flags.frames, "mesh files (.drc .ply .obj .glb), e.g. out/frame_*.ply")
      ->type_name("FRAME...");
  preview->add_option("-o,--output", flags.dir, "directory for <frame>.png (created)")->type_name("DIR");
  preview->add_option("--size", flags.size, "picture size in pixels (default 480x360)")->type_name("WxH");
  preview
      ->add_option("--azimuth", flags.options.azimuth_degrees,
                   "camera direction around the vertical (z) axis, degrees from +x (default -60)")
      ->type_name("DEG");
  preview
      ->add_option("--elevation", flags.options.elevation_degrees,
                   "camera height above the horizontal, degrees, -89..89 (default 25)")
      ->check(CLI::Range(-89.0, 89.0))
      ->type_name("DEG");
  preview
      ->add_option("--particles", flags.particles,
                   "particle file or pattern (any format `run particles --input` reads) drawn as dots over the "
                   "surface; one file per frame, in the frames' order")
      ->type_name("FILE|PATTERN");
  preview
      ->add_option("--iterations", flags.iterations,
                   "an optimize run's iterations.csv: also plot e_d and e_n per iteration (log scale) as "
                   "DIR/iterations.png")
      ->type_name("CSV");
  preview->footer(std::string("Examples:\n"
                              "  surfacer preview out/seq/frame_*.drc -o out/seq/preview\n"
                              "  surfacer preview out/fluid/frame_0000.ply --particles sim/fluid_0000.bgeo -o pics/\n"
                              "  surfacer preview --iterations out/opt/iterations.csv -o out/opt/preview\n"
                              "The camera is framed on the union of every frame's bounds, so a sequence does not "
                              "jump. Prints the\npictures' paths.\n\n") +
                  kGlobalNote);
  return preview;
}

PreviewCommand finish_preview(const PreviewFlags& flags) {
  PreviewCommand command;
  if (!flags.dir || flags.dir->empty()) {
    throw CliError(ExitCode::kUsage, "preview needs an output directory: -o DIR");
  }
  if (flags.frames.empty() && !flags.iterations) {
    throw CliError(ExitCode::kUsage,
                   "preview needs frame files (e.g. out/frame_*.ply) or --iterations out/iterations.csv");
  }
  command.dir = *flags.dir;
  for (const std::string& f : flags.frames) command.frames.emplace_back(f);
  if (flags.iterations) command.iterations_csv = *flags.iterations;
  command.options = flags.options;
  const std::size_t x = flags.size.find('x');
  std::int64_t w = 0, h = 0;
  if (x == std::string::npos || !parse_int(flags.size.substr(0, x), w) || !parse_int(flags.size.substr(x + 1), h) ||
      w < 16 || h < 16 || w > 8192 || h > 8192) {
    throw CliError(ExitCode::kUsage, "--size " + flags.size +
                                         " must be WIDTHxHEIGHT in pixels, each 16..8192, e.g. "
                                         "480x360");
  }
  command.options.width = static_cast<int>(w);
  command.options.height = static_cast<int>(h);
  if (!flags.particles.empty()) {
    if (command.frames.empty()) throw CliError(ExitCode::kUsage, "--particles needs frame files to draw over");
    ParticleInputOptions input;
    input.inputs = flags.particles;
    command.options.particles = expand_particle_inputs(input, "--particles");
  }
  return command;
}

}  // namespace surfacer::client
