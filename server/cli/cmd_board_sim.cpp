// fringe board-sim: an emulated Modbus board (libmodbus server) for tests and demos.
#include "server/cli/commands.hpp"
#include "drivers/sim/board_sim.hpp"
#include "estimator/estimator.hpp"

#include <atomic>
#include <csignal>
#include <cstdio>

namespace fringe::cli {

namespace {

using nlohmann::json;

struct BoardSimCli {
    dev::BoardSimOptions o;
    std::vector<std::string> params;
};

std::atomic<bool> g_sim_stop{false};
void on_sim_signal(int) { g_sim_stop = true; }

int run_board_sim_cli(BoardSimCli& c) {
    if (!c.params.empty()) {
        const auto& info = est::find(c.o.estimator);
        c.o.params = parse_param_assignments(info.params, c.params);
    }
    c.o.stop = &g_sim_stop;
    std::signal(SIGINT, on_sim_signal);
    std::signal(SIGTERM, on_sim_signal);
    c.o.on_listening = [&](const std::string& where) {
        std::printf("board-sim %s (%s) listening on %s\n", c.o.board.c_str(), c.o.estimator.c_str(), where.c_str());
        std::fflush(stdout);
    };
    const long long n = dev::run_board_sim(c.o);
    std::printf("board-sim: %lld requests answered%s\n", n, g_sim_stop ? "" : " (stopped by a fault option)");
    return kExitOk;
}

}  // namespace

Command add_board_sim(CLI::App& app) {
    auto c = std::make_shared<BoardSimCli>();
    auto* bs = app.add_subcommand("board-sim", "An emulated Modbus board (libmodbus server) for tests and demos");
    bs->add_option("--modbus", c->o.listen, "tcp://127.0.0.1:PORT (0: a free port, printed) or rtu:/dev/ttyX")->required();
    bs->add_option("--board", c->o.board, "Board profile name (fixtures/boards) or path")->capture_default_str();
    bs->add_option("--unit", c->o.unit, "Modbus unit id (RTU)")->capture_default_str();
    bs->add_option("--baud", c->o.baud, "RTU baud rate")->capture_default_str();
    bs->add_option("--estimator", c->o.estimator, "On-board estimator of a DUT board (any registered)")->capture_default_str();
    bs->add_option("--param", c->params, "On-board estimator parameter key=value (repeatable)");
    bs->add_option("--offset-sin-v", c->o.offset_sin_v, "Analog path flaw: sin offset, V");
    bs->add_option("--offset-cos-v", c->o.offset_cos_v, "Analog path flaw: cos offset, V");
    bs->add_option("--gain-mismatch", c->o.gain_mismatch, "Analog path flaw: sin gain 1+g/2, cos gain 1-g/2");
    bs->add_option("--noise-v", c->o.noise_v, "ADC input noise, V rms per conversion");
    bs->add_option("--adc-bits", c->o.adc_bits, "ADC resolution (0: ideal)")->capture_default_str();
    bs->add_option("--adc-range-v", c->o.adc_range_v, "ADC full scale, V")->capture_default_str();
    bs->add_option("--seed", c->o.seed, "Noise seed")->capture_default_str();
    bs->add_option("--exception-every", c->o.exception_every, "Fault: every Nth request answers with a Modbus exception");
    bs->add_option("--delay-ms", c->o.delay_ms, "Fault: delay every reply");
    bs->add_option("--delay-from", c->o.delay_from, "Fault: --delay-ms starts at request N (counted from 1)")->capture_default_str();
    bs->add_option("--delay-count", c->o.delay_count, "Fault: --delay-ms applies to this many requests (-1: all)")->capture_default_str();
    bs->add_option("--trickle-ms", c->o.trickle_ms, "Fault: send every reply one byte at a time, this many ms apart");
    bs->add_option("--drop-after", c->o.drop_after, "Fault (kill): after N requests close every connection and stop");
    bs->add_option("--freeze-after", c->o.freeze_after, "Fault: after N requests keep the connections but never answer");
    bs->add_option("--restart-after", c->o.restart_after, "Fault: after N requests reset every connection, stay away --restart-down-ms, listen again on the same port with fresh registers (TCP, once)");
    bs->add_option("--restart-down-ms", c->o.restart_down_ms, "Fault: how long a restart keeps the port closed")->capture_default_str();
    bs->add_option("--stale-adc-after", c->o.stale_adc_after, "Fault: after N ADC conversions the input registers stop updating (old data repeated)");
    bs->add_option("--nan-adc-after", c->o.nan_adc_after, "Fault: after N ADC conversions sin_in reads NaN (float registers)");
    return {bs, [c] { return run_board_sim_cli(*c); }};
}

}  // namespace fringe::cli
