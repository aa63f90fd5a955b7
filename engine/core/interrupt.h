// Interrupting a render and keeping what was done.
//
// The engine never installs signal handlers itself (a program embedding it
// may have its own); the fluxgraph CLI does, and its handlers use only what
// this header marks async-signal-safe. The model:
//
//  - A pass does its work in units (a sample pass of `pt`, a photon batch of
//    `photon`; the scheduler counts an iteration of a repeat block as one). It
//    reports each finished unit (PassContext::completedUnit) and, between
//    units, asks whether to stop (PassContext::stopRequested). A pass that
//    stops says what it kept (PassContext::keptPartial); the rest of the
//    pipeline then runs on what was made, and the outputs say they are partial.
//  - A stop request before any unit has finished cannot keep anything; the
//    CLI then quits at once instead of asking for one.
//  - Output temporaries and the directories made for them are registered here
//    while they exist, so that a handler that quits can remove them.
#pragma once

#include <cstdint>
#include <string>

namespace fg {

// Asks every running pass to stop at its next unit boundary. Async-signal-safe.
void requestStop() noexcept;
// Async-signal-safe.
bool stopRequested() noexcept;
// A unit of work finished somewhere in this process (pass threads; the
// async-signal-safe reader is completedUnits()).
void noteCompletedUnit();
std::uint64_t completedUnits() noexcept;
// Forgets stop requests and finished units (before a new render in the same
// process, and between tests).
void resetStopState() noexcept;

// Paths to remove if the process is killed before they are renamed or cleaned
// up. Registration copies the path into a fixed table (paths too long or a
// full table are simply not registered: best effort, never an allocation in
// the handler).
void registerTemporaryFile(const std::string& path) noexcept;
void registerCreatedDirectory(const std::string& path) noexcept;
void unregisterCleanupPath(const std::string& path) noexcept;
// Unlinks every registered file, then removes every registered directory
// (newest first; a directory something else has written into stays).
// Async-signal-safe.
void removeRegisteredPaths() noexcept;

// Quitting on a signal: removes the registered paths, writes `message` (one
// line) to stderr and ends the process with exit code 128 + signal, without
// running destructors or atexit handlers. Async-signal-safe.
[[noreturn]] void quitAfterSignal(int signal, const char* message) noexcept;
// While outputs are being renamed onto their final names (OutputCommit::commit)
// a quitting signal is held back: half the outputs renamed and the rest
// removed would be the one state worse than either. A handler calls
// deferQuitIfCommitting first; it returns true when the quit was deferred,
// and leaveCommitSection then quits (the outputs are complete by then).
// Async-signal-safe.
bool deferQuitIfCommitting(int signal, const char* message) noexcept;
void enterCommitSection() noexcept;
void leaveCommitSection() noexcept;

// Test hook: with FLUXGRAPH_TEST_PAUSE set to a comma-separated list of points
// ("start": after loading, before the first pass; "unit:N": once N units have
// finished; "write": when every output is written to its temporary, before
// any rename), the process prints "fluxgraph-test: paused at POINT" on stderr
// at each of them and waits (at most 60 s) for the next stop request (a
// signal that quits ends the wait too, with the process). Tests
// use it to deliver signals at exact points of a render; without the variable
// it costs one branch.
void pauseForTest(const std::string& point);

}  // namespace fg
