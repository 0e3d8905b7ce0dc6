// board-sim (the emulated Modbus board) on a free port of 127.0.0.1 in a thread, for tests;
// stops on destruction.
#pragma once

#include "drivers/sim/board_sim.hpp"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>

namespace fringe::test {

struct SimThread {
    dev::BoardSimOptions o;
    std::atomic<bool> stop{false};
    std::thread t;
    std::mutex mu;
    std::condition_variable cv;
    std::string where;
    long long answered = -1;
    std::string failure;
    explicit SimThread(dev::BoardSimOptions opt) : o(std::move(opt)) {
        o.listen = "tcp://127.0.0.1:0";
        o.stop = &stop;
        o.on_listening = [this](const std::string& w) {
            std::lock_guard<std::mutex> l(mu);
            where = w;
            cv.notify_all();
        };
        t = std::thread([this] {
            try {
                answered = dev::run_board_sim(o);
            } catch (const std::exception& e) {
                std::lock_guard<std::mutex> l(mu);
                failure = e.what();
                where = "failed";
                cv.notify_all();
            }
        });
        std::unique_lock<std::mutex> l(mu);
        cv.wait_for(l, std::chrono::seconds(5), [&] { return !where.empty(); });
    }
    ~SimThread() { finish(); }
    // Stops the board; the number of requests it answered.
    long long finish() {
        stop = true;
        if (t.joinable()) t.join();
        return answered;
    }
    std::string uri(const std::string& query) const {
        return "modbus+tcp://" + where.substr(6) + "?" + query;
    }
};

}  // namespace fringe::test
