// A fixed set of worker threads that run one batch of independent tasks at a time; the caller
// works too and returns when the batch is done. The run engine's pipeline steps use it: the
// frame source, each lane and the traces of different blocks side by side, each task on data no
// other task of the batch touches, so results do not depend on the thread count.
//
// Batches come every few milliseconds during a run, about as often as a sleeping thread takes
// to be woken on a busy machine: so waiting (a worker for the next batch, the caller for the
// end of one) first spins for up to kSpin, yielding (on an oversubscribed machine the thread it
// waits for may need this very core), and only then sleeps on a condition variable.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace fringe {

class TaskPool {
public:
    static constexpr std::chrono::microseconds kSpin{2000};

    // threads: the total (the caller included); 1 runs every task on the caller, in order.
    explicit TaskPool(unsigned threads) {
        for (unsigned i = 1; i < threads; ++i) workers_.emplace_back([this] { work(); });
    }
    ~TaskPool() {
        {
            std::lock_guard lock(m_);
            stop_.store(true);
        }
        cv_.notify_all();
        for (auto& w : workers_) w.join();
    }
    TaskPool(const TaskPool&) = delete;
    TaskPool& operator=(const TaskPool&) = delete;

    unsigned threads() const { return static_cast<unsigned>(workers_.size()) + 1; }

    // Runs every task; each task's exception is kept in errors[i] (null when it finished).
    void run(const std::vector<std::function<void()>>& tasks, std::vector<std::exception_ptr>& errors) {
        errors.assign(tasks.size(), nullptr);
        if (workers_.empty() || tasks.size() < 2) {
            for (std::size_t i = 0; i < tasks.size(); ++i) call(tasks[i], errors[i]);
            return;
        }
        {
            std::lock_guard lock(m_);
            tasks_ = &tasks;
            errors_ = &errors;
            next_.store(0);
            pending_.store(tasks.size());
            batch_.fetch_add(1);
        }
        cv_.notify_all();
        drain(&tasks, &errors);
        // Every task done, and no worker still inside this batch (it holds its pointers).
        auto done = [this] { return pending_.load() == 0 && active_.load() == 0; };
        spin_until(done);
        if (!done()) {
            std::unique_lock lock(m_);
            done_cv_.wait(lock, done);
        }
        std::lock_guard lock(m_);
        tasks_ = nullptr;
        errors_ = nullptr;
    }

private:
    static void call(const std::function<void()>& f, std::exception_ptr& err) {
        try {
            f();
        } catch (...) {
            err = std::current_exception();
        }
    }
    template <class Pred>
    static void spin_until(Pred p) {
        const auto until = std::chrono::steady_clock::now() + kSpin;
        while (!p() && std::chrono::steady_clock::now() < until) std::this_thread::yield();
    }
    // Takes tasks of the current batch until none is left.
    void drain(const std::vector<std::function<void()>>* tasks, std::vector<std::exception_ptr>* errors) {
        for (;;) {
            const std::size_t i = next_.fetch_add(1);
            if (i >= tasks->size()) return;
            call((*tasks)[i], (*errors)[i]);
            if (pending_.fetch_sub(1) == 1) {
                std::lock_guard lock(m_);  // the caller may be between its check and its wait
                done_cv_.notify_all();
            }
        }
    }
    void work() {
        std::uint64_t seen = 0;
        for (;;) {
            spin_until([&] { return stop_.load() || batch_.load() != seen; });
            const std::vector<std::function<void()>>* tasks = nullptr;
            std::vector<std::exception_ptr>* errors = nullptr;
            {
                std::unique_lock lock(m_);
                cv_.wait(lock, [&] { return stop_.load() || (batch_.load() != seen && tasks_ != nullptr); });
                if (stop_.load()) return;
                seen = batch_.load();
                tasks = tasks_;
                errors = errors_;
                active_.fetch_add(1);
            }
            drain(tasks, errors);
            if (active_.fetch_sub(1) == 1) {
                std::lock_guard lock(m_);
                done_cv_.notify_all();
            }
        }
    }

    std::vector<std::thread> workers_;
    std::mutex m_;
    std::condition_variable cv_, done_cv_;
    const std::vector<std::function<void()>>* tasks_ = nullptr;  // guarded by m_
    std::vector<std::exception_ptr>* errors_ = nullptr;          // guarded by m_
    std::atomic<std::size_t> next_{0};
    std::atomic<std::size_t> pending_{0};
    std::atomic<std::size_t> active_{0};  // workers inside the current batch
    std::atomic<std::uint64_t> batch_{0};
    std::atomic<bool> stop_{false};
};

}  // namespace fringe
