#include "server/http/run_manager.hpp"

#include "server/engine/run.hpp"
#include "drivers/device.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <stdexcept>

namespace fringe {

using nlohmann::json;

namespace {
std::int64_t unix_ms() {
    return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch()).count();
}
constexpr std::size_t kKeepFinished = 256;  // finished runs kept in memory; older ones come from the store
}

void to_json(json& j, const RunSnapshot& s) {
    j = json{{"id", s.id}, {"scenario", s.scenario}, {"dut", s.dut}, {"created_at", s.created_at}, {"status", s.status},
             {"device", s.device},
             {"progress", {{"done", s.done}, {"total", s.total}, {"fraction", s.total ? static_cast<double>(s.done) / static_cast<double>(s.total) : 0.0}}},
             {"seq", s.seq}, {"updated_unix_ms", s.updated_unix_ms}};
    j["verdict"] = s.verdict.empty() ? json(nullptr) : json(s.verdict);
    j["error"] = s.error.empty() ? json(nullptr) : json(s.error);
}

// The queue's key for a device: the resolved device the lock is taken on (127.0.0.1 and 127.1
// are one board), so a run waits here for a board another run of this service holds; a board
// held by another process ends the run as ERROR "busy" when it opens (drivers/device.hpp).
std::string device_key(const std::string& uri) {
    const auto colon = uri.find(':');
    const std::string scheme = colon == std::string::npos ? uri : uri.substr(0, colon);
    if (scheme == "loopback" || scheme == "capture") return "";
    try {
        if (std::string k = dev::DeviceLock::key_for(uri); !k.empty()) return k;
    } catch (const std::exception&) {  // a bad URI: the run names it when it opens
    }
    return uri.substr(0, uri.find('?'));
}

RunManager::RunManager(RunStore& store, std::mutex& store_mu, unsigned workers) : store_(store), store_mu_(store_mu) {
    if (workers == 0) workers = 1;
    for (unsigned i = 0; i < workers; ++i) threads_.emplace_back([this] { worker(); });
}

RunManager::~RunManager() { shutdown(); }

std::string RunManager::submit(RunPlan plan) {
    const Scenario& sc = plan.scenario;
    {
        std::lock_guard<std::mutex> l(mu_);
        if (stopping_) throw std::runtime_error("the service is shutting down");
        if (max_queued > 0 && queue_.size() + submitting_ >= max_queued)
            throw QueueFull(std::to_string(queue_.size() + submitting_) + " runs are already queued (at most " + std::to_string(max_queued) +
                            ", --max-queued-runs); retry when some have started");
        ++submitting_;
    }
    struct Admitted {  // the slot is given back however submit() ends
        RunManager& m;
        ~Admitted() {
            std::lock_guard<std::mutex> l(m.mu_);
            --m.submitting_;
        }
    } admitted{*this};
    auto job = std::make_shared<Job>();
    job->snap.id = new_run_id();
    job->snap.scenario = sc.name;
    job->snap.dut = sc.dut;
    job->snap.device = sc.device_label();
    job->snap.created_at = iso_now();
    job->snap.status = "queued";
    job->snap.total = sc.samples();
    job->snap.seq = 1;
    job->snap.updated_unix_ms = unix_ms();
    for (const auto& [field, uri] : sc.device_uris())
        if (const std::string k = device_key(uri); !k.empty() && std::find(job->keys.begin(), job->keys.end(), k) == job->keys.end()) job->keys.push_back(k);
    job->provenance = make_provenance(provenance, sc);
    if (job->snap.dut.empty()) job->snap.dut = job->provenance["dut"]["serial"].get<std::string>();
    job->sc = sc;
    job->plan.emplace(std::move(plan));
    {
        std::lock_guard<std::mutex> sl(store_mu_);
        store_.begin(job->snap.id, job->snap.created_at, job->snap.scenario, job->snap.dut, "queued", job->provenance);
    }
    {
        std::lock_guard<std::mutex> l(mu_);
        if (stopping_) throw std::runtime_error("the service is shutting down");
        jobs_[job->snap.id] = job;
        queue_.push_back(job);
    }
    cv_.notify_all();
    return job->snap.id;
}

RunManager::CancelResult RunManager::cancel(const std::string& id) {
    std::unique_lock<std::mutex> l(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return CancelResult::Unknown;
    auto job = it->second;
    if (job->snap.finished()) return CancelResult::Finished;
    job->cancel = true;
    if (job->snap.status == "queued") {
        // Never started: it ends here, with a report saying so.
        for (auto q = queue_.begin(); q != queue_.end(); ++q)
            if (*q == job) { queue_.erase(q); break; }
        job->plan.reset();  // its estimators are not needed any more
        job->snap.status = "aborted";
        job->snap.verdict = "ABORTED";
        job->snap.error = "cancelled while queued";
        ++job->snap.seq;
        job->snap.updated_unix_ms = unix_ms();
        const json report = unstarted_report(job->sc, id, job->snap.created_at, RunStatus::Aborted, Verdict::Aborted, "cancelled while queued", job->provenance);
        finished_order_.push_back(id);
        l.unlock();
        {
            std::lock_guard<std::mutex> sl(store_mu_);
            store_.finish(report);
        }
        changed_.notify_all();
        if (on_finished) on_finished(report);
    }
    return CancelResult::Cancelled;
}

std::optional<RunSnapshot> RunManager::snapshot(const std::string& id) const {
    std::lock_guard<std::mutex> l(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return std::nullopt;
    return it->second->snap;
}

std::vector<RunSnapshot> RunManager::live() const {
    std::lock_guard<std::mutex> l(mu_);
    std::vector<RunSnapshot> out;
    for (const auto& [id, job] : jobs_)
        if (!job->snap.finished()) out.push_back(job->snap);
    return out;
}

std::optional<RunSnapshot> RunManager::wait_change(const std::string& id, std::uint64_t after_seq, int timeout_ms) const {
    std::unique_lock<std::mutex> l(mu_);
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return std::nullopt;
    auto job = it->second;
    changed_.wait_for(l, std::chrono::milliseconds(timeout_ms), [&] { return job->snap.seq > after_seq || job->snap.finished(); });
    return job->snap;
}

std::shared_ptr<RunManager::Job> RunManager::next_job_locked() {
    for (auto q = queue_.begin(); q != queue_.end(); ++q) {
        const auto& job = *q;
        bool busy = false;
        for (const auto& k : job->keys) busy |= busy_keys_[k] > 0;
        if (busy) continue;  // a board of it is in use: keep its place
        auto picked = job;
        queue_.erase(q);
        return picked;
    }
    return nullptr;
}

void RunManager::worker() {
    for (;;) {
        std::shared_ptr<Job> job;
        {
            std::unique_lock<std::mutex> l(mu_);
            cv_.wait(l, [&] { return stopping_ || (job = next_job_locked()) != nullptr; });
            if (!job) return;  // stopping
            for (const auto& k : job->keys) ++busy_keys_[k];
            job->snap.status = "running";
            ++job->snap.seq;
        job->snap.updated_unix_ms = unix_ms();
        }
        changed_.notify_all();
        try {
            std::lock_guard<std::mutex> sl(store_mu_);
            store_.set_status(job->snap.id, "running");
        } catch (const std::exception& e) {  // the store is away: the run goes on, its report is stored at the end
            spdlog::warn("run {}: could not mark it running: {}", job->snap.id, e.what());
        }
        RunOptions ro;
        ro.run_id = job->snap.id;
        ro.cancel = &job->cancel;
        ro.provenance = job->provenance;
        ro.calibration_dir = calibration_dir;
        ro.progress = [this, job](std::uint64_t done, std::uint64_t total) {
            {
                std::lock_guard<std::mutex> l(mu_);
                job->snap.done = done;
                job->snap.total = total;
                ++job->snap.seq;
                job->snap.updated_unix_ms = unix_ms();
            }
            changed_.notify_all();
        };
        json report;
        try {
            RunPlan plan = std::move(*job->plan);
            job->plan.reset();
            report = execute_run(std::move(plan), ro);
        } catch (const std::exception& e) {  // validation passed at submit; anything here is a bug or the environment
            report = unstarted_report(job->sc, job->snap.id, job->snap.created_at, RunStatus::Error, Verdict::Error, e.what(), job->provenance);
        } catch (...) {  // a worker never dies with a run
            report = unstarted_report(job->sc, job->snap.id, job->snap.created_at, RunStatus::Error, Verdict::Error, "the run failed with an unknown exception", job->provenance);
        }
        bool interrupted;
        {
            std::lock_guard<std::mutex> l(mu_);
            interrupted = job->interrupted;
        }
        if (interrupted && report.value("status", "") == "aborted") {
            report["status"] = "interrupted";
            report["error"] = "interrupted: the service shut down during the run";
        }
        if (max_report_bytes > 0) {
            const std::size_t bytes = report.dump(-1, ' ', false, json::error_handler_t::replace).size();
            if (bytes > max_report_bytes) {
                const auto processed = report["samples"].value("processed", std::uint64_t{0});
                report = unstarted_report(job->sc, job->snap.id, job->snap.created_at, RunStatus::Error, Verdict::Error,
                                          "the report is " + std::to_string(bytes) + " bytes; this service stores at most " +
                                              std::to_string(max_report_bytes) + " (--max-report-mb)", job->provenance);
                report["samples"]["processed"] = processed;
            }
        }
        try {
            std::lock_guard<std::mutex> sl(store_mu_);
            store_.finish(report);
        } catch (const std::exception& e) {
            // A verdict that is not stored is not a finished run: the run becomes an error,
            // visibly, and its row is marked so if the store still takes a status.
            spdlog::error("run {}: could not store the report: {}", job->snap.id, e.what());
            report["status"] = "error";
            report["verdict"] = "ERROR";
            report["error"] = std::string("the report could not be stored: ") + e.what();
            try {
                std::lock_guard<std::mutex> sl(store_mu_);
                store_.set_status(job->snap.id, "error");
            } catch (const std::exception&) {
            }
        }
        {
            std::lock_guard<std::mutex> l(mu_);
            for (const auto& k : job->keys) --busy_keys_[k];
            job->snap.status = report.value("status", "error");
            job->snap.verdict = report.value("verdict", "ERROR");
            job->snap.error = report["error"].is_string() ? report["error"].get<std::string>() : "";
            job->snap.done = report["samples"].value("processed", job->snap.done);
            ++job->snap.seq;
        job->snap.updated_unix_ms = unix_ms();
            job->sc = Scenario{};  // the report has it now
            job->plan.reset();
            finished_order_.push_back(job->snap.id);
            while (finished_order_.size() > kKeepFinished) {
                jobs_.erase(finished_order_.front());
                finished_order_.pop_front();
            }
        }
        changed_.notify_all();
        cv_.notify_all();  // a board may be free for a queued run
        try {
            if (on_finished) on_finished(report);
        } catch (const std::exception& e) {
            spdlog::error("run {}: after the run: {}", job->snap.id, e.what());
        }
        spdlog::info("run {} ({}): {} {}", job->snap.id, job->snap.scenario, job->snap.status, job->snap.verdict);
    }
}

void RunManager::shutdown() {
    std::lock_guard<std::mutex> once(shutdown_mu_);  // concurrent callers wait for the first to finish
    std::vector<std::shared_ptr<Job>> queued;
    {
        std::lock_guard<std::mutex> l(mu_);
        if (stopping_ && threads_.empty()) return;
        stopping_ = true;
        for (auto& [id, job] : jobs_)
            if (job->snap.status == "running") {
                job->interrupted = true;
                job->cancel = true;
            }
        queued.assign(queue_.begin(), queue_.end());
        queue_.clear();
        for (auto& job : queued) {
            job->snap.status = "interrupted";
            job->snap.verdict = "ABORTED";
            job->snap.error = "interrupted: the service shut down before the run started";
            ++job->snap.seq;
        job->snap.updated_unix_ms = unix_ms();
        }
    }
    cv_.notify_all();
    changed_.notify_all();
    for (auto& t : threads_) t.join();
    threads_.clear();
    std::lock_guard<std::mutex> sl(store_mu_);
    for (auto& job : queued) {
        try {
            store_.set_status(job->snap.id, "interrupted");
        } catch (const std::exception& e) {
            spdlog::error("run {}: {}", job->snap.id, e.what());
        }
    }
}

}  // namespace fringe
