// Job files: what to render and how. A job is TOML:
//
//   scene    = "../cornell-box/cornell-box.toml"  # relative to the job file (.toml or Mitsuba .xml)
//   scene_defines = { spp = "64" }  # optional: parameters of a Mitsuba scene (its $name /
//                                   # <default>); strings, numbers or booleans; --define wins
//   pipeline = "pt"                 # a built-in pipeline, or a [pipeline] table (below)
//   seed     = 1                    # random streams are keyed by (seed, pass instance, item)
//   threads  = 0                    # 0 = all hardware threads
//
//   [film]                          # optional; width/height default to the scene camera's
//   width = 256
//   height = 256
//   filter = "gaussian"             # "box" | "tent" | "gaussian"
//   filter_radius = 1.5             # pixels
//   gaussian_sigma = 0.5            # pixels
//
//   [output]
//   directory = "out"               # relative to the working directory
//   name = "cornell"                # file stem; default: the job file's stem
//   exr = true                      # linear float EXR with metadata and AOV channels
//   png = true                      # sRGB preview
//   exposure = 0.0                  # stops, PNG preview only
//   half = false                    # EXR colour channels as 16-bit half floats (reference images)
//
//   [passes.pt]                     # parameters of the pass instance "pt"
//   spp = 64
//
// A custom pipeline lists its passes in order (slots bind to buffers of the
// same name unless `inputs`/`outputs` rename them):
//
//   [pipeline]
//   name = "my-pt"
//   results = ["image"]
//   [[pipeline.pass]]
//   pass = "pt"                     # registered pass
//   name = "pt"                     # instance name (default: the pass name)
//   outputs = { image = "image" }
//
// A repeat block runs its passes `count` times (see RepeatBlock in pass.h):
//
//   [[pipeline.repeat]]
//   name = "progressive"
//   count = 64
//   carry = { image = "image" }     # iteration i+1 reads iteration i's image
//   until = "noise.converged"       # optional: stop when pass instance noise raises it
//   seconds = 60                    # optional: stop after the iteration that ends past 60 s
//   [[pipeline.repeat.pass]]
//   pass = "pt"
//
//   [import]                        # buffers read from files (fluxgraph render --save) instead of made
//   photons = "photons.fgbuf"
//
// Every key is checked: unknown keys, wrong types and nonsense values are
// errors naming the file and line.
#pragma once

#include "engine/image/film.h"
#include "engine/core/scheduler.h"

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace fg {

// One bound for `threads` in job files and --threads on any command line.
inline constexpr int kMaxThreads = 4096;

struct OutputSettings {
    std::string directory = ".";
    std::string name;
    bool exr = true;
    bool png = true;
    float exposure = 0.0f;
    bool half = false;  // half-float EXR colour channels; the AOVs stay 32-bit
};

struct Job {
    std::string path;      // the job file
    std::string text;      // its full text, stored in the EXR metadata
    std::string scenePath; // resolved against the job file's directory
    std::map<std::string, std::string> sceneDefines;  // scene_defines merged with --define
    Pipeline pipeline;
    JobParams params;
    FilmSettings film;
    bool filmSizeGiven = false;    // otherwise the scene camera's resolution is used
    bool filmFilterGiven = false;  // otherwise the scene's filter hint (if any) is used
    int threads = 0;
    std::uint64_t seed = 1;
    OutputSettings output;
    std::vector<std::string> overrides;  // the --set arguments, for the metadata
    BufferFiles bufferFiles;  // [import] and --import, --save
};

struct JobOverrides {
    std::vector<std::string> sets;  // "passes.pt.spp=64", "film.width=128", ...
    std::vector<std::string> defines;  // "--define name=value": scene parameters, override scene_defines
    std::optional<int> threads;
    std::optional<std::uint64_t> seed;
    std::optional<std::string> outputDirectory;
    std::vector<std::string> imports;  // "--import NAME=path"
    std::vector<std::string> saves;    // "--save NAME=path"
};

// Throws InputError naming file:line (or the --set argument) on any problem.
// `registry` names the built-in pipelines (default: the installed registry).
Job loadJob(const std::string& path, const JobOverrides& overrides = {}, const Registry& registry = installedRegistry());
Job parseJob(const std::string& text, const std::string& path, const JobOverrides& overrides = {},
             const Registry& registry = installedRegistry());
// A pipeline file (passes/pipelines/*.toml): one [pipeline] table in the job
// format, plus `doc`. Throws InputError naming the file and line.
Pipeline parsePipelineFile(const std::string& text, const std::string& path);

}  // namespace fg
