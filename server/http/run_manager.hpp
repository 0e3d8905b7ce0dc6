// The service's run queue: a pool of worker threads running execute_run, with exclusive use
// of a device. Runs on the same board (same device URI without its query) queue one after
// the other; runs on simulated or file devices (loopback:, capture:) go in parallel, up to
// the number of workers. Every run is in the store from the moment it is queued; its report
// is written there in one transaction when it ends. Live progress is kept in memory.
#pragma once

#include "server/engine/plan.hpp"
#include "server/engine/provenance.hpp"
#include "server/engine/scenario.hpp"
#include "server/store/store.hpp"

#include <nlohmann/json.hpp>

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace fringe {

// What a client sees of a run: status queued | running | done | error | aborted | interrupted.
struct RunSnapshot {
    std::string id, scenario, dut, created_at, status, verdict, error, device;
    std::uint64_t done = 0, total = 0;
    std::uint64_t seq = 0;  // increases on every change: progress events compare it
    std::int64_t updated_unix_ms = 0;  // wall clock of the last change (event latency is measured against it)
    bool finished() const { return status != "queued" && status != "running"; }
};
void to_json(nlohmann::json& j, const RunSnapshot& s);

// Runs on this device key exclude each other; "" means no exclusion (simulated devices).
std::string device_key(const std::string& uri);

// submit() when max_queued runs already wait: the client should retry later (429).
struct QueueFull : std::runtime_error {
    using std::runtime_error::runtime_error;
};

class RunManager {
public:
    // store_mu guards every use of store (shared with the HTTP handlers).
    RunManager(RunStore& store, std::mutex& store_mu, unsigned workers);
    ~RunManager();
    RunManager(const RunManager&) = delete;
    RunManager& operator=(const RunManager&) = delete;

    // Queues a run plan (plan_run: the scenario checked, its estimators built); returns its id. Throws QueueFull when max_queued runs are
    // already waiting (nothing stored), std::runtime_error after shutdown.
    std::string submit(RunPlan plan);
    // Asks a queued or running run to stop (it ends ABORTED). False if unknown or finished.
    enum class CancelResult { Cancelled, Unknown, Finished };
    CancelResult cancel(const std::string& id);
    // Live state of a run this process knows (queued, running or recently finished).
    std::optional<RunSnapshot> snapshot(const std::string& id) const;
    std::vector<RunSnapshot> live() const;  // queued and running
    // Blocks until the run's seq exceeds after_seq, it finishes, or the timeout passes.
    std::optional<RunSnapshot> wait_change(const std::string& id, std::uint64_t after_seq, int timeout_ms) const;
    unsigned workers() const { return static_cast<unsigned>(threads_.size()); }
    // Graceful shutdown: running runs stop after their current block and are stored as
    // "interrupted" with their partial report; queued runs are marked "interrupted".
    void shutdown();
    // Called (from a worker thread) when a run's report has been stored.
    std::function<void(const nlohmann::json& report)> on_finished;
    // A report larger than this (serialised, bytes; 0: no bound) is not stored: the run ends
    // as an error whose report says how large it was.
    std::size_t max_report_bytes = 0;
    // Runs waiting for a worker or their board (not yet running) at most; 0: no bound.
    std::size_t max_queued = 0;
    // The service's bench, host, DUT and operator (a scenario's dut / dut_part win): each
    // run's report["provenance"] and row.
    ProvenanceDefaults provenance = provenance_defaults();
    // Where a calibrated run writes its correction file (RunOptions::calibration_dir; the
    // service's DATA/corrections); empty: the engine's temporary folder.
    std::string calibration_dir;

private:
    struct Job {
        RunSnapshot snap;
        Scenario sc;  // the plan's, for the snapshots and a report of a run that never started
        std::optional<RunPlan> plan;  // until a worker runs it
        std::vector<std::string> keys;  // its devices' keys (output and input instruments: both)
        std::atomic<bool> cancel{false};
        bool interrupted = false;  // cancelled by shutdown
        nlohmann::json provenance;
    };
    void worker();
    std::shared_ptr<Job> next_job_locked();

    RunStore& store_;
    std::mutex& store_mu_;
    mutable std::mutex mu_;
    std::mutex shutdown_mu_;
    mutable std::condition_variable cv_;         // work for the workers
    mutable std::condition_variable changed_;    // progress for the waiters
    std::deque<std::shared_ptr<Job>> queue_;
    std::map<std::string, std::shared_ptr<Job>> jobs_;  // queued, running and the last finished
    std::deque<std::string> finished_order_;
    std::map<std::string, int> busy_keys_;
    std::size_t submitting_ = 0;  // admitted by submit(), not yet in queue_ (their rows are being stored)
    bool stopping_ = false;
    std::vector<std::thread> threads_;
};

}  // namespace fringe
