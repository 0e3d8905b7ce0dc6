// Steps per second through the Modbus driver over loopback TCP against board-sim, beside a
// plain libmodbus loop doing the same requests (write 2 registers, read 2 input registers)
// on the same link. Both talk to one board-sim thread on this machine.
//   build/perf/bench_modbus [seconds per measurement]
#include "drivers/sim/board_sim.hpp"
#include "drivers/device.hpp"

#include <modbus/modbus.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>
#include <thread>

using namespace fringe::dev;
using clk = std::chrono::steady_clock;

int main(int argc, char** argv) {
    const double secs = argc > 1 ? std::atof(argv[1]) : 3.0;
    std::atomic<bool> stop{false};
    std::mutex mu;
    std::condition_variable cv;
    std::string where;
    BoardSimOptions o;
    o.listen = "tcp://127.0.0.1:0";
    o.board = "generic-aio";
    o.stop = &stop;
    o.on_listening = [&](const std::string& w) {
        std::lock_guard<std::mutex> l(mu);
        where = w;
        cv.notify_all();
    };
    std::thread sim([&] { run_board_sim(o); });
    {
        std::unique_lock<std::mutex> l(mu);
        cv.wait(l, [&] { return !where.empty(); });
    }
    const std::string hp = where.substr(6);
    const int port = std::stoi(hp.substr(hp.rfind(':') + 1));

    // Plain libmodbus: the same two requests per step.
    modbus_t* ctx = modbus_new_tcp("127.0.0.1", port);
    if (modbus_connect(ctx) == -1) { std::fprintf(stderr, "connect: %s\n", modbus_strerror(errno)); return 2; }
    auto plain = [&](double s) {
        std::uint16_t w[2], r[2];
        long n = 0;
        const auto t0 = clk::now();
        while (clk::now() - t0 < std::chrono::duration<double>(s)) {
            w[0] = static_cast<std::uint16_t>(n & 0x7fff);
            w[1] = static_cast<std::uint16_t>((n * 7) & 0x7fff);
            if (modbus_write_registers(ctx, 0, 2, w) != 2 || modbus_read_input_registers(ctx, 0, 2, r) != 2) {
                std::fprintf(stderr, "libmodbus: %s\n", modbus_strerror(errno));
                std::exit(2);
            }
            ++n;
        }
        return static_cast<double>(n) / std::chrono::duration<double>(clk::now() - t0).count();
    };
    // The driver: step(sin, cos), no settle, one reading.
    auto dev = open("modbus+tcp://" + hp + "?board=generic-aio&settle_s=0&average=1");
    auto driver = [&](double s) {
        long n = 0;
        const auto t0 = clk::now();
        while (clk::now() - t0 < std::chrono::duration<double>(s)) {
            const double th = 0.01 * static_cast<double>(n);
            dev->step()->measure(std::sin(th), std::cos(th), 0.0, 1);
            ++n;
        }
        return static_cast<double>(n) / std::chrono::duration<double>(clk::now() - t0).count();
    };
    // Interleaved rounds after a warm-up, so both see the same machine state.
    plain(0.3);
    driver(0.3);
    double plain_sum = 0, drv_sum = 0;
    const int rounds = 4;
    for (int i = 0; i < rounds; ++i) {
        plain_sum += plain(secs / rounds);
        drv_sum += driver(secs / rounds);
    }
    const double plain_rate = plain_sum / rounds, drv_rate = drv_sum / rounds;
    modbus_close(ctx);
    modbus_free(ctx);
    dev.reset();
    stop = true;
    sim.join();
    std::printf("plain libmodbus (write 2 + read 2 registers): %8.0f steps/s\n", plain_rate);
    std::printf("fringe modbus driver step():                %8.0f steps/s (%.1f %% of plain)\n", drv_rate, 100.0 * drv_rate / plain_rate);
    return 0;
}
