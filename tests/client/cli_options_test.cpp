// Command-line parsing of the `surfacer` CLI: no server involved.
#include <gtest/gtest.h>

#include <sstream>

#include "client/cli.h"
#include "tests/support/cli_parse.h"

namespace surfacer::client {
namespace {

using surfacer::testing::exit_code_of;
using surfacer::testing::parse_cli;
using surfacer::testing::ParsedCli;

const Invocation& ok(const ParsedCli& p) {
  EXPECT_TRUE(std::holds_alternative<Invocation>(p.result)) << p.err;
  return std::get<Invocation>(p.result);
}

TEST(CliOptions, RunIsosurfaceDefaults) {
  auto p = parse_cli({"run", "isosurface", "--scene", "a.json", "-o", "out"});
  const Invocation& inv = ok(p);
  EXPECT_TRUE(inv.connect.local());
  const auto& run = std::get<RunCommand>(inv.command);
  ASSERT_TRUE(run.job.spec.has_isosurface());
  EXPECT_EQ(run.job.scenes.size(), 1u);
  // The 128 default is the server's: the CLI sends no resolution.
  EXPECT_EQ(run.job.spec.isosurface().resolution_case(), v1::IsosurfaceJob::RESOLUTION_NOT_SET);
  EXPECT_EQ(run.job.spec.output().encoding(), v1::MESH_ENCODING_UNSPECIFIED);
  EXPECT_EQ(run.output.dir, "out");
  EXPECT_TRUE(run.output.formats.empty());
}

TEST(CliOptions, RunIsosurfaceAllFlags) {
  auto p = parse_cli(
      {"run",       "isosurface",          "--scene",  "a.json", "--scene", "b.json",   "--cell-size", "0.05",
       "--bounds",  "-1,-2,-3,1,2,3",      "--method", "cubes",  "-o",      "out",      "--format",    "ply,obj",
       "--normals", "--quantization-bits", "12",       "--name", "demo",    "--server", "host:1234",   "--timeout",
       "2"});
  const Invocation& inv = ok(p);
  EXPECT_EQ(inv.connect.server, "host:1234");
  EXPECT_DOUBLE_EQ(inv.connect.timeout_seconds, 2.0);
  const auto& run = std::get<RunCommand>(inv.command);
  ASSERT_TRUE(run.job.spec.has_isosurface());
  EXPECT_EQ(run.job.scenes.size(), 2u);
  EXPECT_EQ(run.job.spec.isosurface().cell_size(), 0.05);
  ASSERT_TRUE(run.job.spec.isosurface().has_bounds());
  EXPECT_EQ(run.job.spec.isosurface().bounds().min().x(), -1.0);
  EXPECT_EQ(run.job.spec.isosurface().bounds().max().z(), 3.0);
  EXPECT_EQ(run.job.spec.isosurface().method(), v1::POLYGONIZER_CUBES);
  EXPECT_EQ(run.output.formats, (std::vector<FileFormat>{FileFormat::kPly, FileFormat::kObj}));
  EXPECT_TRUE(run.job.spec.output().normals());
  EXPECT_EQ(run.job.spec.output().quantization_bits(), 12);
  EXPECT_EQ(run.job.name, "demo");
}

TEST(CliOptions, GlobalOptionsBeforeSubcommand) {
  auto p = parse_cli({"--server", "h:1", "run", "--spec", "job.json", "-o", "d"});
  const Invocation& inv = ok(p);
  EXPECT_EQ(inv.connect.server, "h:1");
  const auto& run = std::get<RunCommand>(inv.command);
  EXPECT_EQ(run.job.spec_file, "job.json");
  EXPECT_FALSE(run.job.spec.has_isosurface());
}

TEST(CliOptions, ServerFromEnvironmentUnlessLocal) {
  EXPECT_EQ(ok(parse_cli({"status", "j1"}, "env:9")).connect.server, "env:9");
  EXPECT_TRUE(ok(parse_cli({"--local", "status", "j1"}, "env:9")).connect.local());
  EXPECT_EQ(ok(parse_cli({"--server", "x:1", "status", "j1"}, "env:9")).connect.server, "x:1");
  EXPECT_TRUE(ok(parse_cli({"status", "j1"}, "")).connect.local());
}

// Flags for one kind of server are refused with the other, naming the flag, rather than ignored.
TEST(CliOptions, ServerKindFlagsRefusedWithTheOtherKind) {
  EXPECT_EQ(ok(parse_cli({"--workers", "3", "list"})).connect.workers, 3);
  EXPECT_EQ(ok(parse_cli({"--local", "--workers", "3", "list"}, "env:9")).connect.workers, 3);
  auto remote = parse_cli({"--workers", "3", "list"}, "env:9");
  EXPECT_EQ(exit_code_of(remote), ExitCode::kUsage);
  EXPECT_NE(remote.err.find("--workers"), std::string::npos) << remote.err;
  EXPECT_NE(remote.err.find("env:9"), std::string::npos) << remote.err;
  EXPECT_TRUE(ok(parse_cli({"--server", "h:1", "--allow-insecure", "list"})).connect.security.allow_insecure);
  auto local = parse_cli({"--allow-insecure", "list"});
  EXPECT_EQ(exit_code_of(local), ExitCode::kUsage);
  EXPECT_NE(local.err.find("--allow-insecure"), std::string::npos) << local.err;
}

// A mistyped flag or subcommand is named with the nearest one the command has; words far from all get none.
TEST(CliOptions, MistypedFlagsAndSubcommandsGetASuggestion) {
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"run", "isosurface", "--scene", "a.json", "--cell", "64", "-o", "d"}, "did you mean --cells for --cell?"},
      {{"run", "isosurfce", "--scene", "a.json", "-o", "d"}, "did you mean isosurface for isosurfce?"},
      {{"run", "particles", "--input", "a", "--r-iner", "0.1", "-o", "d"}, "--r-inner for --r-iner"},
      {{"run", "particles", "--input", "a", "--r-inner", "0.1", "--min-angel=3", "-o", "d"},
       "--min-angle for --min-angel"},
      {{"run", "optimize", "--scene", "a.json", "--iteratoins", "5", "-o", "d"}, "--iterations for --iteratoins"},
  };
  for (const auto& [args, expected] : cases) {
    const auto p = parse_cli(args);
    EXPECT_EQ(exit_code_of(p), ExitCode::kUsage);
    EXPECT_NE(p.err.find(expected), std::string::npos) << p.err;
  }
  const auto far = parse_cli({"run", "isosurface", "--scene", "a.json", "--zzzzzzzz", "-o", "d"});
  EXPECT_EQ(exit_code_of(far), ExitCode::kUsage);
  EXPECT_EQ(far.err.find("did you mean"), std::string::npos) << far.err;
}

// A port outside 1..65535 is refused before connecting (gRPC would take it modulo 65536), in every address form.
TEST(CliOptions, ServerPortsOutOfRangeAreUsageErrors) {
  for (const char* server : {"127.0.0.1:99999", "127.0.0.1:0", "[::1]:65536", "dns:///host:123456", "a:1,b:70000"}) {
    const auto p = parse_cli({"--server", server, "run", "--spec", "job.json", "-o", "d"});
    EXPECT_EQ(exit_code_of(p), ExitCode::kUsage) << server;
    EXPECT_NE(p.err.find("is not a TCP port"), std::string::npos) << server << ": " << p.err;
  }
  for (const char* server : {"127.0.0.1:65535", "[::1]:1", "host:50051,other:50052"}) {
    EXPECT_EQ(exit_code_of(parse_cli({"--server", server, "run", "--spec", "job.json", "-o", "d"})), ExitCode::kSuccess)
        << server;
  }
}

TEST(CliOptions, OtherSubcommands) {
  auto watch = std::get<WatchCommand>(ok(parse_cli({"watch", "j-7", "--from-frame", "3", "-o", "d"})).command);
  EXPECT_EQ(watch.job_id, "j-7");
  EXPECT_EQ(watch.from_frame, 3);
  auto list = std::get<ListCommand>(ok(parse_cli({"list", "--state", "running,queued"})).command);
  EXPECT_EQ(list.states, (std::vector<std::string>{"running", "queued"}));
  EXPECT_EQ(std::get<CancelCommand>(ok(parse_cli({"cancel", "j-1"})).command).job_id, "j-1");
  EXPECT_EQ(std::get<StatusCommand>(ok(parse_cli({"status", "j-2"})).command).job_id, "j-2");
  EXPECT_TRUE(std::holds_alternative<HealthCommand>(ok(parse_cli({"health"})).command));
  auto submit = std::get<SubmitCommand>(ok(parse_cli({"submit", "isosurface", "--scene", "a.json", "--raw"})).command);
  EXPECT_EQ(submit.job.spec.output().encoding(), v1::MESH_ENCODING_PLY);
}

TEST(CliOptions, UsageErrorsExitTwo) {
  const std::vector<std::vector<std::string>> bad = {
      {},
      {"frobnicate"},
      {"run", "isosurface", "-o", "d"},                                                      // no --scene
      {"run", "isosurface", "--scene", "a.json"},                                            // no -o
      {"run", "-o", "d"},                                                                    // no job
      {"run", "--spec", "j.json", "-o", "d", "isosurface", "--scene", "a.json"},             // both
      {"run", "isosurface", "--scene", "a", "--cells", "8", "--cell-size", "1", "-o", "d"},  // exclusive
      {"run", "isosurface", "--scene", "a", "--bounds", "1,2,3", "-o", "d"},
      {"run", "isosurface", "--scene", "a", "--bounds", "1,0,0,0,1,1", "-o", "d"},  // min > max
      {"run", "isosurface", "--scene", "a", "--format", "stl", "-o", "d"},
      {"run", "isosurface", "--scene", "a", "--quantization-bits", "31", "-o", "d"},
      {"run", "isosurface", "--scene", "a", "--raw", "--quantization-bits", "10", "-o", "d"},
      {"run", "isosurface", "--scene", "a", "--method", "hexes", "-o", "d"},
      {"--server", "h:1", "--local", "health"},
      {"--server", "h:1", "--workers", "2", "list"},  // sizes only the in-process server
      {"--allow-insecure", "--local", "list"},        // no token goes anywhere
      {"watch", "-o", "d"},
      {"list", "--state", "sleeping"},
  };
  for (const auto& args : bad) {
    auto p = parse_cli(args);
    std::string joined;
    for (const auto& a : args) joined += a + " ";
    EXPECT_EQ(exit_code_of(p), ExitCode::kUsage) << joined;
    EXPECT_NE(p.err.find("surfacer: error: "), std::string::npos) << joined << "\n" << p.err;
  }
}

TEST(CliOptions, HelpListsExampleAndExitCodes) {
  auto p = parse_cli({"--help"});
  EXPECT_EQ(exit_code_of(p), ExitCode::kSuccess);
  EXPECT_NE(p.out.find("Exit codes"), std::string::npos);
  EXPECT_NE(p.out.find("6  frame integrity error"), std::string::npos);
  for (const char* sub : {"run", "submit", "watch", "status", "list", "cancel", "health"}) {
    auto h = parse_cli({sub, "--help"});
    EXPECT_EQ(exit_code_of(h), ExitCode::kSuccess) << sub;
    EXPECT_NE(h.out.find("Example"), std::string::npos) << sub << "\n" << h.out;
  }
  auto iso = parse_cli({"run", "isosurface", "--help"});
  EXPECT_EQ(exit_code_of(iso), ExitCode::kSuccess);
  EXPECT_NE(iso.out.find("--scene"), std::string::npos);
  EXPECT_NE(iso.out.find("Example"), std::string::npos);
}

}  // namespace
}  // namespace surfacer::client
