// End-to-end tests of the `fluxgraph` executable: each test spawns the real
// binary through the shell, then checks its exit code, what it printed and
// what it left on disk. Input errors must cost exactly one stderr line and
// exit code 2 and leave no image behind; renders must be reproducible across
// thread counts and carry their provenance in the EXR metadata.
#include "passes/passes.h"
#include "engine/image/image_io.h"
#include "engine/core/pass.h"

#include "tests/support/cli_helpers.h"
#include "tests/support/small_filesystem.h"

#include <gtest/gtest.h>

#include <sys/stat.h>
#include <sys/wait.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

using test::CommandResult;
using test::readText;
using test::runFluxgraph;
using test::sourcePath;
using test::writeText;

fs::path scratchDirectory() { return test::scratchDirectory("cli"); }

std::string quickstartJob() { return sourcePath("data/jobs/quickstart.toml"); }
std::string cornellScene() { return sourcePath("data/cornell-box/cornell-box.toml"); }

// Small enough that a render takes well under a second, large enough that the
// path tracer splits it into several chunks (so thread counts matter).
std::vector<std::string> tinyRender(std::vector<std::string> args) {
    for (const char* set : {"film.width=32", "film.height=32", "passes.pt.spp=2"}) {
        args.push_back("--set");
        args.push_back(set);
    }
    return args;
}

std::vector<std::string> listDirectory(const fs::path& dir) {
    std::vector<std::string> names;
    if (!fs::exists(dir)) return names;
    for (const auto& entry : fs::directory_iterator(dir)) names.push_back(entry.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
}

// Every file below `dir`, recursively, relative to it (logs excluded).
std::vector<std::string> filesBelow(const fs::path& dir) {
    std::vector<std::string> names;
    if (!fs::exists(dir)) return names;
    for (const auto& entry : fs::recursive_directory_iterator(dir)) {
        const std::string relative = fs::relative(entry.path(), dir).string();
        if (relative.rfind("logs", 0) == 0) continue;
        if (!entry.is_directory()) names.push_back(relative);
    }
    std::sort(names.begin(), names.end());
    return names;
}

std::string joined(const std::vector<std::string>& names) {
    std::string text;
    for (const auto& n : names) text += (text.empty() ? "" : ", ") + n;
    return text;
}

bool isImage(const std::string& name) {
    const std::string ext = fs::path(name).extension().string();
    return ext == ".exr" || ext == ".png";
}

// The input-error contract: exit code 2 and exactly one line on stderr.
void expectInputError(const CommandResult& r) {
    EXPECT_EQ(r.exitCode, 2) << "stderr: " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "stderr: " << r.err;
    EXPECT_TRUE(!r.err.empty() && r.err.back() == '\n') << "stderr: " << r.err;
    EXPECT_EQ(r.err.find("internal error"), std::string::npos) << "stderr: " << r.err;
}

const ParamSpec& ptParam(const std::string& name) {
    const PassRegistration* pt = findPass("pt");
    if (!pt) throw std::runtime_error("pass 'pt' is not registered");
    for (const ParamSpec& p : pt->spec.params)
        if (p.name == name) return p;
    throw std::runtime_error("pass 'pt' has no parameter '" + name + "'");
}

std::map<std::string, std::string> asMap(const Metadata& metadata) {
    return {metadata.begin(), metadata.end()};
}

// A minimal JSON syntax check (RFC 8259 grammar, no semantic checks), enough
// to tell a well-formed trace from a truncated or mis-escaped one.
class JsonChecker {
public:
    explicit JsonChecker(const std::string& text) : text_(text) {}
    bool valid() {
        skipSpace();
        if (!value()) return false;
        skipSpace();
        return pos_ == text_.size();
    }

private:
    void skipSpace() {
        while (pos_ < text_.size() && std::isspace(static_cast<unsigned char>(text_[pos_]))) ++pos_;
    }
    bool consume(char c) {
        skipSpace();
        if (pos_ < text_.size() && text_[pos_] == c) {
            ++pos_;
            return true;
        }
        return false;
    }
    bool literal(const char* word) {
        const std::size_t n = std::strlen(word);
        if (text_.compare(pos_, n, word) != 0) return false;
        pos_ += n;
        return true;
    }
    bool string() {
        if (!consume('"')) return false;
        while (pos_ < text_.size()) {
            const char c = text_[pos_++];
            if (c == '"') return true;
            if (static_cast<unsigned char>(c) < 0x20) return false;
            if (c == '\\') {
                if (pos_ >= text_.size()) return false;
                const char e = text_[pos_++];
                if (e == 'u') {
                    for (int i = 0; i < 4; ++i)
                        if (pos_ >= text_.size() || !std::isxdigit(static_cast<unsigned char>(text_[pos_++]))) return false;
                } else if (std::strchr("\"\\/bfnrt", e) == nullptr) {
                    return false;
                }
            }
        }
        return false;
    }
    bool number() {
        const std::size_t start = pos_;
        if (pos_ < text_.size() && text_[pos_] == '-') ++pos_;
        std::size_t digits = 0;
        while (pos_ < text_.size() && std::isdigit(static_cast<unsigned char>(text_[pos_]))) ++pos_, ++digits;
        if (digits == 0) return false;
        if (pos_ < text_.size() && text_[pos_] == '.') {
            ++pos_;
            digits = 0;
            while (pos_ < text_.size() && std::isdigit(static_cast<unsigned char>(text_[pos_]))) ++pos_, ++digits;
            if (digits == 0) return false;
        }
        if (pos_ < text_.size() && (text_[pos_] == 'e' || text_[pos_] == 'E')) {
            ++pos_;
            if (pos_ < text_.size() && (text_[pos_] == '+' || text_[pos_] == '-')) ++pos_;
            digits = 0;
            while (pos_ < text_.size() && std::isdigit(static_cast<unsigned char>(text_[pos_]))) ++pos_, ++digits;
            if (digits == 0) return false;
        }
        return pos_ > start;
    }
    bool value() {
        skipSpace();
        if (pos_ >= text_.size()) return false;
        const char c = text_[pos_];
        if (c == '{') {
            ++pos_;
            if (consume('}')) return true;
            do {
                skipSpace();
                if (!string() || !consume(':') || !value()) return false;
            } while (consume(','));
            return consume('}');
        }
        if (c == '[') {
            ++pos_;
            if (consume(']')) return true;
            do {
                if (!value()) return false;
            } while (consume(','));
            return consume(']');
        }
        if (c == '"') return string();
        if (c == 't') return literal("true");
        if (c == 'f') return literal("false");
        if (c == 'n') return literal("null");
        return number();
    }

    const std::string& text_;
    std::size_t pos_ = 0;
};

std::size_t countOccurrences(const std::string& text, const std::string& needle) {
    std::size_t count = 0;
    for (std::size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + needle.size())) ++count;
    return count;
}

TEST(JsonChecker, AcceptsJsonAndRejectsBrokenText) {
    EXPECT_TRUE(JsonChecker(R"({"a":[1,2.5,-3e2,"x\"y",true,null],"b":{}})").valid());
    EXPECT_FALSE(JsonChecker(R"({"a":[1,2})").valid());
    EXPECT_FALSE(JsonChecker(R"({"a":1,})").valid());
    EXPECT_FALSE(JsonChecker("{\"a\":\"line\nbreak\"}").valid());
}

// ---------------------------------------------------------------- input errors

TEST(Cli, MalformedJobNamesFileAndLine) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "broken.toml").string();
    writeText(job, "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\nseed = = 1\n");
    const CommandResult r = runFluxgraph(dir, {"render", job, "--out", (dir / "out").string()});
    expectInputError(r);
    EXPECT_EQ(r.err.rfind(job + ":3:", 0), 0u) << r.err;
    EXPECT_TRUE(filesBelow(dir).size() == 1) << joined(filesBelow(dir));  // the job file only
}

TEST(Cli, MissingSceneIsNamedAndNothingIsWritten) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"no-such-scene.toml\"\npipeline = \"pt\"\n[film]\nwidth = 16\nheight = 16\n");
    const fs::path out = dir / "out";
    const CommandResult r = runFluxgraph(dir, {"render", job, "--out", out.string()});
    expectInputError(r);
    EXPECT_NE(r.err.find((dir / "no-such-scene.toml").string()), std::string::npos) << r.err;
    const std::vector<std::string> written = listDirectory(out);
    EXPECT_TRUE(std::none_of(written.begin(), written.end(), isImage)) << joined(written);
    EXPECT_TRUE(written.empty()) << "left behind: " << joined(written);
}

TEST(Cli, OutputBelowARegularFileIsRejectedBeforeRendering) {
    const fs::path dir = scratchDirectory();
    writeText(dir / "afile", "not a directory\n");
    const fs::path out = dir / "afile" / "sub";
    const CommandResult r = runFluxgraph(dir, tinyRender({"render", quickstartJob(), "--out", out.string()}));
    expectInputError(r);
    EXPECT_NE(r.err.find(out.string()), std::string::npos) << r.err;
    EXPECT_EQ(filesBelow(dir), std::vector<std::string>{"afile"});
    EXPECT_EQ(readText(dir / "afile"), "not a directory\n");
}

TEST(Cli, NegativeSampleCountReportsTheValidRange) {
    const fs::path dir = scratchDirectory();
    const fs::path out = dir / "out";
    const ParamSpec& spp = ptParam("spp");
    std::ostringstream rangeText;
    rangeText << '[' << static_cast<std::int64_t>(spp.minValue) << ", " << static_cast<std::int64_t>(spp.maxValue) << ']';
    const std::string range = rangeText.str();
    const CommandResult r = runFluxgraph(
        dir, {"render", quickstartJob(), "--out", out.string(), "--set", "film.width=32", "--set", "film.height=32",
              "--set", "passes.pt.spp=-4"});
    expectInputError(r);
    EXPECT_NE(r.err.find("spp"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("-4"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(range), std::string::npos) << "expected " << range << " in: " << r.err;
    EXPECT_TRUE(filesBelow(dir).empty()) << joined(filesBelow(dir));
}

TEST(Cli, UnknownPassParameterNamesFileAndLine) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"" + cornellScene() +
                       "\"\npipeline = \"pt\"\n\n[film]\nwidth = 16\nheight = 16\n\n[passes.pt]\nspp = 2\n"
                       "samples_per_pixel = 8\n");
    const CommandResult r = runFluxgraph(dir, {"render", job, "--out", (dir / "out").string()});
    expectInputError(r);
    EXPECT_EQ(r.err.rfind(job + ":10:", 0), 0u) << r.err;
    EXPECT_NE(r.err.find("samples_per_pixel"), std::string::npos) << r.err;
    EXPECT_EQ(filesBelow(dir), std::vector<std::string>{"job.toml"});
}

TEST(Cli, NegativeThreadCountIsAnInputError) {
    const fs::path dir = scratchDirectory();
    const CommandResult r =
        runFluxgraph(dir, tinyRender({"render", quickstartJob(), "--out", (dir / "out").string(), "--threads", "-1"}));
    expectInputError(r);
    EXPECT_NE(r.err.find("threads"), std::string::npos) << r.err;
    EXPECT_TRUE(filesBelow(dir).empty()) << joined(filesBelow(dir));
}

// The trace is written after the render, so its destination must be checked
// before it: a bad --profile path may not cost a finished render's images.
TEST(Cli, UnwritableProfilePathIsRejectedBeforeRendering) {
    const fs::path dir = scratchDirectory();
    const fs::path out = dir / "out";
    for (const fs::path& trace : {dir / "no-such-directory" / "trace.json", out}) {
        const CommandResult r = runFluxgraph(
            dir, tinyRender({"render", quickstartJob(), "--quiet", "--out", out.string(), "--profile", trace.string()}));
        expectInputError(r);
        EXPECT_NE(r.err.find(trace.string()), std::string::npos) << r.err;
        EXPECT_NE(r.err.find("profile"), std::string::npos) << r.err;
        EXPECT_TRUE(filesBelow(dir).empty()) << "left behind: " << joined(filesBelow(dir));
    }
}

// A render whose noise makes the PNG about 130 KiB, and whose trace holds one
// event of about 110 bytes per stream of 256 paths: 1024 of them, about 110 KiB.
std::vector<std::string> renderTooBigFor64KiB(std::vector<std::string> args) {
    for (const char* set : {"film.width=256", "film.height=256", "passes.pt.spp=4"}) {
        args.push_back("--set");
        args.push_back(set);
    }
    return args;
}

// OpenImageIO's PNG writer ignores failed writes: a full disk once gave a
// truncated PNG and exit 0.
TEST(Cli, AFullDiskIsAnInputErrorAndLeavesNeitherImagesNorTheOutputDirectory) {
    const fs::path dir = scratchDirectory();
    const fs::path small = dir / "small";
    test::SmallFilesystem filesystem(small, 64 * 1024);
    FG_SKIP_UNLESS_MOUNTED(filesystem);
    const fs::path out = small / "new" / "out";
    for (const bool exr : {false, true}) {
        SCOPED_TRACE(exr ? "EXR and PNG" : "PNG only");
        const CommandResult r = runFluxgraph(
            dir, renderTooBigFor64KiB({"render", quickstartJob(), "--quiet", "--out", out.string(), "--set",
                                       exr ? "output.exr=true" : "output.exr=false"}));
        expectInputError(r);
        const std::string image = (out / (exr ? "quickstart.exr" : "quickstart.png")).string();
        EXPECT_EQ(r.err, image + ": cannot write: No space left on device\n");
        EXPECT_TRUE(listDirectory(small).empty()) << "left behind: " << joined(listDirectory(small));
    }
}

// Outputs are committed as a set: a PNG that cannot take its name costs the
// EXR, the trace and the statistics too.
TEST(Cli, APngNameTakenByADirectoryLeavesNoOtherOutput) {
    const fs::path dir = scratchDirectory();
    const fs::path out = dir / "out";
    fs::create_directories(out / "quickstart.png");
    const CommandResult r = runFluxgraph(
        dir, tinyRender({"render", quickstartJob(), "--quiet", "--out", out.string(), "--profile",
                         (out / "trace.json").string(), "--stats", (out / "stats.json").string()}));
    expectInputError(r);
    EXPECT_EQ(r.err, (out / "quickstart.png").string() + ": cannot write: is a directory\n");
    EXPECT_EQ(listDirectory(out), std::vector<std::string>{"quickstart.png"});
}

// The trace is written last; when it does not fit, the images written before
// it go too, and so does the output directory the run made.
TEST(Cli, ATraceThatDoesNotFitLeavesNoImagesAndNoNewOutputDirectory) {
    const fs::path dir = scratchDirectory();
    const fs::path small = dir / "small";
    test::SmallFilesystem filesystem(small, 64 * 1024);
    FG_SKIP_UNLESS_MOUNTED(filesystem);
    const fs::path trace = small / "trace.json";
    const CommandResult r = runFluxgraph(dir, renderTooBigFor64KiB({"render", quickstartJob(), "--quiet", "--out",
                                                                    (dir / "new" / "out").string(), "--profile",
                                                                    trace.string(), "--stats", "stats.json"}));
    expectInputError(r);
    EXPECT_EQ(r.err, trace.string() + ": cannot write: No space left on device\n");
    EXPECT_FALSE(fs::exists(dir / "new"));
    EXPECT_FALSE(fs::exists(dir / "stats.json"));
    EXPECT_TRUE(listDirectory(small).empty()) << "left behind: " << joined(listDirectory(small));
}

TEST(Cli, AStatsPathThatIsADirectoryRemovesTheNewOutputDirectory) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(
        dir, tinyRender({"render", quickstartJob(), "--quiet", "--out", (dir / "new" / "out").string(), "--stats",
                         dir.string()}));
    expectInputError(r);
    EXPECT_NE(r.err.find(dir.string() + ": cannot write statistics: is a directory"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir / "new"));
    EXPECT_TRUE(filesBelow(dir).empty()) << "left behind: " << joined(filesBelow(dir));
}

TEST(Cli, ValidateReportsAMissingScene) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"missing/scene.toml\"\npipeline = \"pt\"\n");
    const CommandResult r = runFluxgraph(dir, {"validate", job});
    expectInputError(r);
    EXPECT_NE(r.err.find((dir / "missing" / "scene.toml").string()), std::string::npos) << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
}

// A path component over the 255-byte file-name limit makes the system calls fail
// with ENAMETOOLONG; that is the user's path, not a defect.
TEST(Cli, OverlongPathComponentsAreInputErrors) {
    const fs::path dir = scratchDirectory();
    const std::string overlong(300, 'a');
    const std::string jobPath = (dir / (overlong + ".toml")).string();
    const CommandResult direct = runFluxgraph(dir, {"validate", jobPath});
    expectInputError(direct);
    EXPECT_EQ(direct.err.rfind(jobPath + ": cannot open job file", 0), 0u) << direct.err;

    for (const std::string& scene : {overlong + ".toml", overlong + "/scene.toml", overlong + ".xml"}) {
        const std::string job = (dir / "job.toml").string();
        writeText(job, "scene = \"" + scene + "\"\npipeline = \"pt\"\n");
        for (const std::string command : {"validate", "render"}) {
            std::vector<std::string> args{command, job};
            if (command == std::string("render")) args.insert(args.end(), {"--out", (dir / "out").string()});
            const CommandResult r = runFluxgraph(dir, args);
            expectInputError(r);
            EXPECT_NE(r.err.find((dir / scene).string()), std::string::npos) << r.err;
        }
    }
    const CommandResult out = runFluxgraph(dir, tinyRender({"render", quickstartJob(), "--out", (dir / overlong).string()}));
    expectInputError(out);
}

TEST(Cli, ValidateRejectsOutputNamesThatCannotBeFiles) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\n\n[output]\nname = \"" +
                       std::string(300, 'n') + "\"\n");
    for (const std::string command : {"validate", "render"}) {
        std::vector<std::string> args{command, job};
        if (command == std::string("render")) args.insert(args.end(), {"--out", (dir / "out").string()});
        const CommandResult r = runFluxgraph(dir, args);
        expectInputError(r);
        EXPECT_EQ(r.err.rfind(job + ":5: output file name", 0), 0u) << r.err;
    }
    writeText(job, "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\n\n[output]\nname = \"a\\u0000b\"\n");
    const CommandResult nul = runFluxgraph(dir, {"validate", job});
    expectInputError(nul);
    EXPECT_EQ(nul.err.rfind(job + ":5: output.name must be a plain file name", 0), 0u) << nul.err;
    EXPECT_EQ(filesBelow(dir), std::vector<std::string>{"job.toml"});
}

TEST(Cli, OutputNameMustBeAPlainFileName) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "job.toml").string();
    for (const std::string name : {"\\u0000", "", "a/b", "..", "."}) {
        writeText(job, "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\n\n[output]\ndirectory = \"out\"\nname = \"" +
                           name + "\"\n");
        for (const std::string command : {"validate", "render"}) {
            const CommandResult r = runFluxgraph(dir, tinyRender({command, job}));
            expectInputError(r);
            EXPECT_EQ(r.err, job + ":6: output.name must be a plain file name (no '/', no NUL, not empty, not '.' or '..')\n")
                << "name = \"" << name << "\"";
        }
    }
    EXPECT_EQ(filesBelow(dir), std::vector<std::string>{"job.toml"});
}

TEST(Cli, OutputDirectoryMustNotBeEmpty) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\n\n[output]\nname = \"image\"\ndirectory = \"\"\n");
    for (const std::string command : {"validate", "render"}) {
        const CommandResult r = runFluxgraph(dir, tinyRender({command, job}));
        expectInputError(r);
        EXPECT_EQ(r.err, job + ":6: output.directory must not be empty\n");
    }
    EXPECT_EQ(filesBelow(dir), std::vector<std::string>{"job.toml"});
}

TEST(Cli, UnknownKeysWithControlOrNonUtf8BytesAreEscaped) {
    const fs::path dir = scratchDirectory();
    const std::string job = (dir / "job.toml").string();
    // TOML lets a quoted key hold \x01 (written as an escape) but not invalid
    // UTF-8, which reaches the same message through --set.
    writeText(job, "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\n\"bad\\u0001key\xc3\xa9\" = 1\n");
    for (const std::string command : {"validate", "render"}) {
        const CommandResult r = runFluxgraph(dir, tinyRender({command, job}));
        expectInputError(r);
        EXPECT_EQ(r.err.rfind(job + ":3: unknown key 'bad\\x01key\xc3\xa9'", 0), 0u) << r.err;
        EXPECT_EQ(r.err.find('\x01'), std::string::npos) << r.err;
    }
    const CommandResult set = runFluxgraph(dir, {"validate", quickstartJob(), "--set", "passes.pt.a\x01\xff\n=1"});
    expectInputError(set);
    EXPECT_EQ(set.err.rfind("--set passes.pt.a\\x01\\xFF\\x0A=1: unknown parameter 'a\\x01\\xFF\\x0A'", 0), 0u)
        << set.err;
    EXPECT_EQ(set.err.find_first_of("\x01\xff"), std::string::npos) << set.err;
    writeText(job, "scene = \"" + cornellScene() + "\"\npipeline = \"pt\"\n\"bad\xffkey\" = 1\n");
    const CommandResult raw = runFluxgraph(dir, {"validate", job});
    expectInputError(raw);
    EXPECT_EQ(raw.err.rfind(job + ":3:", 0), 0u) << raw.err;
    EXPECT_EQ(raw.err.find('\xff'), std::string::npos) << raw.err;
}

// libpng prints its own "libpng error: ..." line on stderr when OIIO reads a
// truncated PNG; that must end up in fluxgraph's one line, not beside it.
TEST(Cli, TruncatedPngTextureOrEnvironmentMapCostsOneLine) {
    const fs::path dir = scratchDirectory();
    const std::string png = readText(sourcePath("data/cornell-box/preview.png"));
    writeText(dir / "half.png", png.substr(0, png.size() / 2));
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"scene.toml\"\npipeline = \"pt\"\n[film]\nwidth = 16\nheight = 16\n");
    const std::string camera = "[camera]\neye = [0, 0, -5]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\nfov = 40\n";
    const std::string texture = "[[material]]\nname = \"t\"\ntype = \"diffuse\"\nreflectance = { bitmap = \"half.png\" }\n";
    const std::string envmap = "[[light]]\ntype = \"envmap\"\nfile = \"half.png\"\n";
    for (const std::string& scene : {camera + texture, camera + envmap}) {
        writeText(dir / "scene.toml", scene);
        for (const std::string command : {"validate", "render"}) {
            const CommandResult r = runFluxgraph(dir, {command, job});
            expectInputError(r);
            // The chunk sizes are checked against the file before libpng reads it.
            EXPECT_NE(r.err.find("half.png: cannot read image: PNG chunk IDAT claims"), std::string::npos) << r.err;
            EXPECT_NE(r.err.find("more than the file holds"), std::string::npos) << r.err;
            EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
            EXPECT_EQ(r.err.rfind((dir / "scene.toml").string() + ":", 0), 0u) << r.err;
        }
    }
    EXPECT_EQ(filesBelow(dir), (std::vector<std::string>{"half.png", "job.toml", "scene.toml"}));
}

TEST(Cli, ThreadCountsHaveOneBound) {
    const fs::path dir = scratchDirectory();
    const CommandResult flag =
        runFluxgraph(dir, tinyRender({"render", quickstartJob(), "--out", (dir / "out").string(), "--threads", "100000"}));
    expectInputError(flag);
    EXPECT_NE(flag.err.find("--threads: must be 0 (all) or a count up to 4096"), std::string::npos) << flag.err;
    const CommandResult set = runFluxgraph(dir, {"validate", quickstartJob(), "--set", "threads=100000"});
    expectInputError(set);
    EXPECT_NE(set.err.find("4096"), std::string::npos) << set.err;
    EXPECT_TRUE(filesBelow(dir).empty()) << joined(filesBelow(dir));
}

TEST(Cli, ValidateRefusesDevicesAndOversizedFiles) {
    const fs::path dir = scratchDirectory();
    for (const std::string& path : {std::string("/dev/zero"), dir.string()}) {
        const CommandResult r = runFluxgraph(dir, {"validate", path});
        expectInputError(r);
        EXPECT_EQ(r.err, path + ": cannot open job file (not a regular file)\n");
    }
    // A scene that is a FIFO would block the reader forever.
    const fs::path fifo = dir / "fifo.toml";
    ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"fifo.toml\"\npipeline = \"pt\"\n");
    const CommandResult scene = runFluxgraph(dir, {"validate", job});
    expectInputError(scene);
    EXPECT_EQ(scene.err, fifo.string() + ": cannot open scene file (not a regular file)\n");
    // Size is checked before reading (a sparse file: no disk space used).
    const fs::path big = dir / "big.toml";
    std::ofstream(big).put('#');
    fs::resize_file(big, 65 * 1024 * 1024);
    const CommandResult oversized = runFluxgraph(dir, {"validate", big.string()});
    expectInputError(oversized);
    EXPECT_EQ(oversized.err, big.string() + ": job file is larger than 64 MiB\n");
    fs::remove(big);
}

// ---------------------------------------------------------------- rendering

TEST(Cli, ThreadCountDoesNotChangeThePixels) {
    const fs::path dir = scratchDirectory();
    Metadata meta1, meta2;
    ImageChannels images[2];
    Metadata* metas[2] = {&meta1, &meta2};
    for (int t = 1; t <= 2; ++t) {
        const fs::path out = dir / ("threads" + std::to_string(t));
        const CommandResult r = runFluxgraph(
            dir, tinyRender({"render", quickstartJob(), "--quiet", "--out", out.string(), "--threads", std::to_string(t)}));
        ASSERT_EQ(r.exitCode, 0) << r.err;
        EXPECT_EQ(listDirectory(out), (std::vector<std::string>{"quickstart.exr", "quickstart.png"}));
        images[t - 1] = readExr((out / "quickstart.exr").string(), metas[t - 1]);
    }
    const ImageChannels& a = images[0];
    const ImageChannels& b = images[1];
    ASSERT_EQ(a.width, 32);
    ASSERT_EQ(a.height, 32);
    ASSERT_EQ(b.width, a.width);
    ASSERT_EQ(b.height, a.height);
    ASSERT_EQ(a.rgb.size(), b.rgb.size());
    double energy = 0.0;
    std::size_t differing = 0;
    for (std::size_t i = 0; i < a.rgb.size(); ++i) {
        for (int c = 0; c < 3; ++c) {
            if (std::memcmp(&a.rgb[i][c], &b.rgb[i][c], sizeof(float)) != 0) ++differing;
            energy += a.rgb[i][c];
        }
    }
    EXPECT_EQ(differing, 0u) << "of " << 3 * a.rgb.size() << " channel values";
    EXPECT_GT(energy, 0.0) << "a black image would make the comparison meaningless";

    for (Metadata* meta : metas) {
        const auto keys = asMap(*meta);
        for (const char* key : {"job", "pipeline", "seed", "pass_timings", "version"})
            EXPECT_TRUE(keys.count(key)) << "missing metadata key " << key;
        EXPECT_EQ(keys.at("job"), readText(quickstartJob()));
        EXPECT_EQ(keys.at("seed"), "1");
        EXPECT_NE(keys.at("pipeline").find("pt"), std::string::npos) << keys.at("pipeline");
        EXPECT_NE(keys.at("pass_timings").find("pt"), std::string::npos) << keys.at("pass_timings");
        EXPECT_FALSE(keys.at("version").empty());
    }
    // The thread limit reached the renderer (otherwise both runs used the same pool).
    EXPECT_EQ(asMap(meta1)["threads"], "1");
    EXPECT_EQ(asMap(meta2)["threads"], "2");
}

TEST(Cli, SeedChangesThePixels) {
    const fs::path dir = scratchDirectory();
    ImageChannels images[2];
    Metadata metas[2];
    const std::string seeds[2] = {"1", "7"};
    for (int i = 0; i < 2; ++i) {
        const fs::path out = dir / ("seed" + seeds[i]);
        const CommandResult r =
            runFluxgraph(dir, tinyRender({"render", quickstartJob(), "--quiet", "--out", out.string(), "--seed", seeds[i]}));
        ASSERT_EQ(r.exitCode, 0) << r.err;
        images[i] = readExr((out / "quickstart.exr").string(), &metas[i]);
        EXPECT_EQ(asMap(metas[i])["seed"], seeds[i]);
    }
    ASSERT_EQ(images[0].rgb.size(), images[1].rgb.size());
    std::size_t differing = 0;
    for (std::size_t i = 0; i < images[0].rgb.size(); ++i) differing += images[0].rgb[i] != images[1].rgb[i] ? 1 : 0;
    // Two samples per pixel of a noisy estimate: nearly every lit pixel should change.
    EXPECT_GT(differing, images[0].rgb.size() / 2) << differing << " of " << images[0].rgb.size() << " pixels differ";
}

TEST(Cli, SuccessfulRenderLeavesNoTemporaryFiles) {
    const fs::path dir = scratchDirectory();
    const fs::path out = dir / "out";
    const CommandResult r = runFluxgraph(
        dir, tinyRender({"render", quickstartJob(), "--out", out.string(), "--profile", (out / "trace.json").string()}));
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const std::vector<std::string> names = listDirectory(out);
    EXPECT_EQ(names, (std::vector<std::string>{"quickstart.exr", "quickstart.png", "trace.json"})) << joined(names);
    for (const std::string& name : names) EXPECT_EQ(name.find(".tmp-"), std::string::npos) << name;
    // The pass table and the list of written files go to stdout, not stderr.
    EXPECT_NE(r.out.find("wrote " + (out / "quickstart.exr").string()), std::string::npos) << r.out;
}

TEST(Cli, ProfileWritesAChromeTrace) {
    const fs::path dir = scratchDirectory();
    const fs::path trace = dir / "trace.json";
    const CommandResult r = runFluxgraph(
        dir, tinyRender({"render", quickstartJob(), "--quiet", "--out", (dir / "out").string(), "--profile", trace.string()}));
    ASSERT_EQ(r.exitCode, 0) << r.err;
    ASSERT_TRUE(fs::exists(trace));
    const std::string json = readText(trace);
    EXPECT_TRUE(JsonChecker(json).valid()) << json.substr(0, 2000);
    EXPECT_NE(json.find("\"traceEvents\""), std::string::npos);
    EXPECT_EQ(countOccurrences(json, "\"name\":\"pt\",\"cat\":\"pass\""), 1u) << json.substr(0, 2000);
    EXPECT_GE(countOccurrences(json, "\"cat\":\"chunk\""), 1u) << json.substr(0, 2000);
    EXPECT_EQ(countOccurrences(json, "\"ph\":\"X\""), countOccurrences(json, "\"cat\":"));
}

// A Mitsuba XML scene whose resolution is a parameter: scene_defines in the
// job sets it, --define overrides that, and an unknown define is an input error.
TEST(Cli, DefinesReachAMitsubaScene) {
    const fs::path dir = scratchDirectory();
    writeText(dir / "scene.xml", R"(<scene version="3.0.0">
    <default name="res" value="4"/>
    <sensor type="perspective">
        <float name="fov" value="60"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>
    </sensor>
    <shape type="rectangle"><bsdf type="diffuse"/></shape>
    <emitter type="point"><point name="position" value="0, 0, 2"/><rgb name="intensity" value="5"/></emitter>
</scene>
)");
    const std::string job = (dir / "job.toml").string();
    writeText(job, "scene = \"scene.xml\"\npipeline = \"pt\"\nscene_defines = { res = 8 }\n[passes.pt]\nspp = 2\n");
    const fs::path out = dir / "out";
    const CommandResult r = runFluxgraph(dir, {"render", job, "--quiet", "--out", out.string(), "--define", "res=12"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    Metadata meta;
    const ImageChannels image = readExr((out / "job.exr").string(), &meta);
    EXPECT_EQ(image.width, 12);
    EXPECT_EQ(image.height, 12);
    EXPECT_EQ(asMap(meta)["scene_defines"], "res=12");

    const CommandResult v = runFluxgraph(dir, {"validate", job});
    EXPECT_EQ(v.exitCode, 0) << v.err;
    const CommandResult typo = runFluxgraph(dir, {"validate", job, "--define", "rez=12"});
    expectInputError(typo);
    EXPECT_NE(typo.err.find("rez"), std::string::npos) << typo.err;
    const CommandResult malformed = runFluxgraph(dir, {"validate", job, "--define", "res"});
    expectInputError(malformed);
    EXPECT_NE(malformed.err.find("--define res"), std::string::npos) << malformed.err;
}

// ---------------------------------------------------------------- inspection commands

TEST(Cli, ValidateAcceptsTheQuickstartJob) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, {"validate", quickstartJob()});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_TRUE(r.err.empty()) << r.err;
    EXPECT_NE(r.out.find("ok"), std::string::npos) << r.out;
    EXPECT_TRUE(filesBelow(dir).empty()) << joined(filesBelow(dir));
}

TEST(Cli, GraphPrintsADotDigraph) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, {"graph", quickstartJob()});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.out.rfind("digraph", 0), 0u) << r.out;
    EXPECT_NE(r.out.find("\"pt\""), std::string::npos) << r.out;
    EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '{'), std::count(r.out.begin(), r.out.end(), '}')) << r.out;
    const std::size_t last = r.out.find_last_not_of(" \n");
    ASSERT_NE(last, std::string::npos);
    EXPECT_EQ(r.out[last], '}') << r.out;
}

TEST(Cli, PassesListsThePathTracerWithItsDefaults) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, {"passes"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    bool listed = false;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);) listed = listed || line.rfind("pt — ", 0) == 0;
    EXPECT_TRUE(listed) << r.out;
    const ParamSpec& spp = ptParam("spp");
    const std::string line = "param spp : " + toString(spp.type) + " = " + toString(spp.defaultValue);
    EXPECT_NE(r.out.find(line), std::string::npos) << "expected '" << line << "' in:\n" << r.out;
}

TEST(Cli, PipelinesListsPt) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, {"pipelines"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    bool found = false;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);) found = found || line.rfind("pt ", 0) == 0;
    EXPECT_TRUE(found) << r.out;
}

TEST(Cli, MissingJobArgumentIsAnInputError) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, {"render"});
    EXPECT_EQ(r.exitCode, 2) << r.err;
    EXPECT_FALSE(r.err.empty());
}

// ---------------------------------------------------------------- iteration, saved and imported buffers

// data/jobs/progressive-pt.toml end to end, small: the repeat block ends early
// on film_noise's condition, its count goes into the metadata, the carried
// film and statistics are saved, and a second run that imports them resumes
// where the first stopped (it converges at once, in one more iteration).
TEST(Cli, ProgressiveJobStopsEarlySavesAndResumes) {
    const fs::path dir = scratchDirectory();
    const std::string job = sourcePath("data/jobs/progressive-pt.toml");
    const std::vector<std::string> small = {"--set", "film.width=24", "--set", "film.height=24",
                                            "--set", "passes.pt.spp=4", "--set", "passes.noise.threshold=0.3"};
    std::vector<std::string> first = {"render", job, "-q", "--out", "first", "--save", "image=first/image.fgbuf",
                                      "--save", "noise=first/noise.fgbuf"};
    first.insert(first.end(), small.begin(), small.end());
    const CommandResult r = runFluxgraph(dir, first);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(listDirectory(dir / "first"),
              (std::vector<std::string>{"image.fgbuf", "noise.fgbuf", "progressive-pt.exr", "progressive-pt.png"}));
    Metadata meta;
    readExr((dir / "first" / "progressive-pt.exr").string(), &meta);
    const std::string iterations = asMap(meta)["iterations"];
    ASSERT_EQ(iterations.rfind("progressive=", 0), 0u) << iterations;
    const int count = std::stoi(iterations.substr(12));
    EXPECT_GE(count, 4);
    EXPECT_LT(count, 64);

    std::vector<std::string> resumed = {"render", job, "-q", "--out", "resumed", "--import", "image=first/image.fgbuf",
                                        "--import", "noise=first/noise.fgbuf"};
    resumed.insert(resumed.end(), small.begin(), small.end());
    const CommandResult again = runFluxgraph(dir, resumed);
    ASSERT_EQ(again.exitCode, 0) << again.err;
    readExr((dir / "resumed" / "progressive-pt.exr").string(), &meta);
    EXPECT_EQ(asMap(meta)["iterations"], "progressive=1");
}

TEST(Cli, ImportedBuffersOfTheWrongKindAreRefusedWithOneLine) {
    const fs::path dir = scratchDirectory();
    const std::string job = sourcePath("data/jobs/progressive-pt.toml");
    ASSERT_EQ(runFluxgraph(dir, {"render", job, "-q", "--out", "out", "--save", "noise=noise.fgbuf", "--set",
                                 "film.width=8", "--set", "film.height=8", "--set", "passes.pt.spp=1"})
                  .exitCode,
              0);
    writeText(dir / "garbage.fgbuf", "not a buffer at all");
    const std::string noise = readText(dir / "noise.fgbuf");
    writeText(dir / "truncated.fgbuf", noise.substr(0, noise.size() / 2));
    for (const char* import : {"image=noise.fgbuf", "image=garbage.fgbuf", "image=truncated.fgbuf", "image=missing.fgbuf"}) {
        const CommandResult r = runFluxgraph(dir, {"render", quickstartJob(), "-q", "--out", "refused", "--import", import});
        expectInputError(r);
        EXPECT_NE(r.err.find(".fgbuf"), std::string::npos) << r.err;
        EXPECT_FALSE(fs::exists(dir / "refused" / "quickstart.exr"));
    }
    EXPECT_NE(runFluxgraph(dir, {"validate", quickstartJob(), "--import", "image=noise.fgbuf"}).err.find("FilmNoise"),
              std::string::npos);
}

// A saved image cut short by one byte or by half: validate refuses it (the
// header's counts give the file's size) as render does, with the same line
// naming the file, exit code 2, and render writes nothing.
TEST(Cli, TruncatedImportsAreRefusedByValidateAndRender) {
    const fs::path dir = scratchDirectory();
    const std::vector<std::string> small = {"--set", "film.width=8", "--set", "film.height=8", "--set",
                                            "passes.pt.spp=1"};
    std::vector<std::string> save = {"render", quickstartJob(), "-q", "--out", "out", "--save", "image=image.fgbuf"};
    save.insert(save.end(), small.begin(), small.end());
    ASSERT_EQ(runFluxgraph(dir, save).exitCode, 0);
    std::vector<std::string> validate = {"validate", quickstartJob(), "--import", "image=image.fgbuf"};
    validate.insert(validate.end(), small.begin(), small.end());
    const CommandResult good = runFluxgraph(dir, validate);
    EXPECT_EQ(good.exitCode, 0) << good.err;
    const std::string image = readText(dir / "image.fgbuf");
    writeText(dir / "short.fgbuf", image.substr(0, image.size() - 1));
    writeText(dir / "half.fgbuf", image.substr(0, image.size() / 2));
    for (const std::string file : {"short.fgbuf", "half.fgbuf"}) {
        std::vector<std::string> args = {quickstartJob(), "--import", "image=" + file};
        args.insert(args.end(), small.begin(), small.end());
        std::vector<std::string> v = {"validate"}, r = {"render", "-q", "--out", "refused"};
        v.insert(v.end(), args.begin(), args.end());
        r.insert(r.end(), args.begin(), args.end());
        const CommandResult checked = runFluxgraph(dir, v);
        expectInputError(checked);
        EXPECT_EQ(checked.err.rfind(file + ": truncated buffer file", 0), 0u) << checked.err;
        const CommandResult rendered = runFluxgraph(dir, r);
        expectInputError(rendered);
        EXPECT_EQ(rendered.err, checked.err);
        EXPECT_FALSE(fs::exists(dir / "refused"));
    }
}

TEST(Cli, ImportsAreCheckedBeforeTheSceneLoads) {
    // A job whose scene is missing and whose import is cut short: validate
    // and render both refuse the import, so it was checked before the scene.
    const fs::path dir = scratchDirectory();
    std::vector<std::string> save = {"render", quickstartJob(), "-q", "--out", "out", "--save", "image=image.fgbuf",
                                     "--set", "film.width=8", "--set", "film.height=8", "--set", "passes.pt.spp=1"};
    ASSERT_EQ(runFluxgraph(dir, save).exitCode, 0);
    const std::string image = readText(dir / "image.fgbuf");
    writeText(dir / "short.fgbuf", image.substr(0, image.size() - 1));
    writeText(dir / "no-scene.toml", "scene = \"no-such-scene.toml\"\npipeline = \"pt\"\n[film]\nwidth = 8\n"
                                     "height = 8\n[passes.pt]\nspp = 1\n");
    for (const std::string command : {"validate", "render"}) {
        std::vector<std::string> args = {command, "no-scene.toml", "--import", "image=short.fgbuf"};
        if (command == "render") args.insert(args.end(), {"-q", "--out", "refused"});
        const CommandResult refused = runFluxgraph(dir, args);
        expectInputError(refused);
        EXPECT_EQ(refused.err.rfind("short.fgbuf: truncated buffer file", 0), 0u) << command << ": " << refused.err;
        EXPECT_EQ(refused.err.find("no-such-scene"), std::string::npos) << refused.err;
    }
    EXPECT_FALSE(fs::exists(dir / "refused"));
}

TEST(Cli, GraphDrawsARepeatBlockOnceUnlessUnrolled) {
    const fs::path dir = scratchDirectory();
    const std::string job = sourcePath("data/jobs/progressive-pt.toml");
    const CommandResult folded = runFluxgraph(dir, {"graph", job});
    ASSERT_EQ(folded.exitCode, 0) << folded.err;
    EXPECT_NE(folded.out.find("repeat progressive x 64, until noise.converged"), std::string::npos) << folded.out;
    EXPECT_EQ(folded.out.find("progressive[1]"), std::string::npos);
    const CommandResult unrolled = runFluxgraph(dir, {"graph", job, "--unroll"});
    ASSERT_EQ(unrolled.exitCode, 0) << unrolled.err;
    EXPECT_NE(unrolled.out.find("\"progressive[63].pt\""), std::string::npos);
    EXPECT_NE(unrolled.out.find("\"progressive[62].pt\" -> \"progressive[63].pt\""), std::string::npos);
}

TEST(Cli, PipelinesListTheirFiles) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, {"pipelines"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    for (const char* name : {"pt", "spm", "pds", "bre", "lt"})
        EXPECT_NE(r.out.find(std::string("file: passes/pipelines/") + name + ".toml"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace fg
