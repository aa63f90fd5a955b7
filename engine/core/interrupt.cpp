// Stop requests and the cleanup table; see interrupt.h.
//
// Everything a signal handler touches is a lock-free atomic or a fixed array
// of characters published through one: no allocation, no lock, nothing a
// handler interrupting the owning thread could find half-changed.
#include "engine/core/interrupt.h"

#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <thread>

namespace fg {

namespace {

std::atomic<std::uint64_t> gStopRequests{0};
std::atomic<std::uint64_t> gCompletedUnits{0};
static_assert(std::atomic<std::uint64_t>::is_always_lock_free, "signal handlers need lock-free atomics");

enum SlotState : int { kFree = 0, kWriting = 1, kFile = 2, kDirectory = 3 };

struct CleanupSlot {
    std::atomic<int> state{kFree};
    std::atomic<std::uint64_t> order{0};
    std::array<char, 4096> path{};
};
// A render stages a handful of outputs (images, trace, statistics, saved
// buffers) and creates a few directories; 256 leaves room for many --save.
std::array<CleanupSlot, 256> gCleanup;
std::atomic<std::uint64_t> gCleanupOrder{0};

void registerPath(const std::string& path, SlotState kind) noexcept {
    if (path.empty() || path.size() >= gCleanup[0].path.size()) return;
    for (CleanupSlot& slot : gCleanup) {
        int expected = kFree;
        if (!slot.state.compare_exchange_strong(expected, kWriting)) continue;
        std::memcpy(slot.path.data(), path.c_str(), path.size() + 1);
        slot.order.store(gCleanupOrder.fetch_add(1) + 1);
        slot.state.store(kind);
        return;
    }
}

std::atomic<bool> gCommitting{false};
std::atomic<int> gDeferredSignal{0};

}  // namespace

void requestStop() noexcept { gStopRequests.fetch_add(1); }
bool stopRequested() noexcept { return gStopRequests.load() > 0; }
void noteCompletedUnit() {
    const std::uint64_t units = gCompletedUnits.fetch_add(1) + 1;
    pauseForTest("unit:" + std::to_string(units));
}
std::uint64_t completedUnits() noexcept { return gCompletedUnits.load(); }
void resetStopState() noexcept {
    gStopRequests.store(0);
    gCompletedUnits.store(0);
}

void registerTemporaryFile(const std::string& path) noexcept { registerPath(path, kFile); }
void registerCreatedDirectory(const std::string& path) noexcept { registerPath(path, kDirectory); }

void unregisterCleanupPath(const std::string& path) noexcept {
    for (CleanupSlot& slot : gCleanup) {
        int state = slot.state.load();
        if (state != kFile && state != kDirectory) continue;
        if (std::strcmp(slot.path.data(), path.c_str()) != 0) continue;
        // Another thread may free the same slot; only one exchange wins.
        if (slot.state.compare_exchange_strong(state, kWriting)) slot.state.store(kFree);
    }
}

void removeRegisteredPaths() noexcept {
    for (CleanupSlot& slot : gCleanup)
        if (slot.state.load() == kFile) ::unlink(slot.path.data());
    // Directories deepest (latest created) first; rmdir leaves non-empty ones.
    for (;;) {
        CleanupSlot* newest = nullptr;
        for (CleanupSlot& slot : gCleanup)
            if (slot.state.load() == kDirectory && (!newest || slot.order.load() > newest->order.load())) newest = &slot;
        if (!newest) break;
        ::rmdir(newest->path.data());
        newest->state.store(kFree);
    }
}

void quitAfterSignal(int signal, const char* message) noexcept {
    removeRegisteredPaths();
    if (message) {
        const std::size_t length = std::strlen(message);
        if (::write(STDERR_FILENO, message, length) < 0) {
            // Nothing to do: the exit code still tells what happened.
        }
    }
    ::_exit(128 + signal);
}

bool deferQuitIfCommitting(int signal, const char* message) noexcept {
    if (!gCommitting.load()) return false;
    gDeferredSignal.store(signal);
    // The commit may have ended between the two checks; then nobody would quit.
    if (gCommitting.load()) return true;
    if (gDeferredSignal.exchange(0) != 0) quitAfterSignal(signal, message);
    return true;
}

void enterCommitSection() noexcept { gCommitting.store(true); }

void leaveCommitSection() noexcept {
    gCommitting.store(false);
    if (const int signal = gDeferredSignal.exchange(0); signal != 0)
        quitAfterSignal(signal, "fluxgraph: interrupted while the outputs were renamed into place; they are complete\n");
}

void pauseForTest(const std::string& point) {
    static const char* const points = std::getenv("FLUXGRAPH_TEST_PAUSE");
    if (!points) return;
    std::istringstream list(points);
    bool wanted = false;
    for (std::string item; std::getline(list, item, ',');) wanted = wanted || item == point;
    if (!wanted) return;
    const std::uint64_t before = gStopRequests.load();
    std::fprintf(stderr, "fluxgraph-test: paused at %s\n", point.c_str());
    std::fflush(stderr);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (gStopRequests.load() == before && std::chrono::steady_clock::now() < deadline)
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
}

}  // namespace fg
