// Defect 8 of issue 10 and "Roles under CURVE": persistent client key pairs
// (`dofarm keygen --client`), an allow-list that works (listing a client key
// used to lock every dofarm client out, since each made a fresh key pair per
// socket) and two roles: worker keys may request, heartbeat and report;
// operator keys may also submit, status, resume and cancel. Real coordinator
// with CURVE, real CLI processes and a real worker.
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

std::string first_line_of(const fs::path& p) {
  std::string text = read_text(p);
  return text.substr(0, text.find('\n'));
}

struct Keys {
  fs::path dir, server_pub, server_key;
  fs::path key(const std::string& name) const { return dir / (name + ".key"); }
  std::string pub(const std::string& name) const { return first_line_of(dir / (name + ".pub")); }
};

Keys make_keys(const TempDir& tmp, const std::vector<std::string>& clients) {
  Keys k{tmp / "keys", tmp / "keys" / "coordinator.pub", tmp / "keys" / "coordinator.key"};
  CliResult r = run_cli(tmp.path(), "keygen", {"keygen", "--out", k.dir.string()});
  if (r.status != 0) throw RuntimeError("keygen: " + r.err);
  for (const std::string& c : clients) {
    r = run_cli(tmp.path(), "keygen-" + c, {"keygen", "--client", c, "--out", k.dir.string()});
    if (r.status != 0) throw RuntimeError("keygen --client " + c + ": " + r.err);
  }
  return k;
}

// The CLI's options for a client with key pair `name`.
std::vector<std::string> as_client(const Keys& k, const std::string& endpoint,
                                   const std::string& name) {
  return {"--coordinator",       endpoint,         "--curve-public",
          k.server_pub.string(), "--curve-client", k.key(name).string()};
}

std::vector<std::string> cat(std::vector<std::string> a, const std::vector<std::string>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

// One call with a client key pair from this process; throws on no reply.
protocol::Message call_as(const Keys& k, const std::string& endpoint,
                          std::optional<std::string> name, const std::string& payload,
                          int timeout_ms = 10000) {
  ClientOptions o{endpoint, k.server_pub, timeout_ms};
  if (name) o.curve_client = k.key(*name);
  return call_coordinator(o, payload);
}

TEST(FarmRoles, WorkerKeyRendersButMaySubmitOrCancelNothing) {
  TempDir tmp;
  const Keys k = make_keys(tmp, {"w1", "op", "stranger"});
  write_text(tmp / "clients.list", "# the farm's clients\n" + k.pub("w1") + " worker w1\n\n" +
                                       k.pub("op") + "   operator\top\n");
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5,
                           {"--curve-secret", k.server_key.string(), "--curve-clients",
                            (tmp / "clients.list").string()});
  const std::string ep = coord.endpoint();
  const fs::path job = write_job(tmp.path(), "job.toml", TinyJob{});
  const std::vector<std::string> submit = {"submit", job.string(), "--out", (tmp / "out").string()};

  // A worker key may not submit: an error reply, nonzero exit, no batch.
  CliResult refused = run_cli(tmp.path(), "submit-w1", cat(submit, as_client(k, ep, "w1")));
  EXPECT_NE(refused.status, 0) << refused.out;
  EXPECT_NE(refused.err.find("worker key may not send \"submit\""), std::string::npos)
      << refused.err;

  // The operator key may.
  CliResult ok = run_cli(tmp.path(), "submit-op", cat(submit, as_client(k, ep, "op")));
  ASSERT_EQ(ok.status, 0) << ok.err;
  const std::string batch = ok.out.substr(0, ok.out.find('\n'));
  CliResult st =
      run_cli(tmp.path(), "status-op", cat({"status", "--json"}, as_client(k, ep, "op")));
  ASSERT_EQ(st.status, 0) << st.err;
  const Json status = Json::parse(st.out);
  ASSERT_EQ(status.at("batches").size(), 1u) << "the worker key's submit made a batch";
  EXPECT_EQ(status.at("batches")[0].at("batch"), batch);

  // Nor may it cancel, resume or read the status.
  for (const std::string op : {"cancel", "resume"}) {
    CliResult r = run_cli(tmp.path(), op + "-w1", cat({op, batch}, as_client(k, ep, "w1")));
    EXPECT_NE(r.status, 0) << op << ": " << r.out;
    EXPECT_NE(r.err.find("worker key may not send \"" + op + "\""), std::string::npos) << r.err;
  }
  CliResult wst = run_cli(tmp.path(), "status-w1", cat({"status"}, as_client(k, ep, "w1")));
  EXPECT_NE(wst.status, 0) << wst.out;

  // A key not on the list, or a fresh key per socket, gets no reply at all.
  EXPECT_THROW(call_as(k, ep, "stranger", protocol::encode("status"), 1500), RuntimeError);
  EXPECT_THROW(call_as(k, ep, std::nullopt, protocol::encode("status"), 1500), RuntimeError);

  // A real worker with the worker key renders the whole batch.
  Child w = start_worker(
      tmp.path(), ep, "w1",
      {"--curve-public", k.server_pub.string(), "--curve-client", k.key("w1").string()});
  ASSERT_TRUE(poll_until(
      "the batch to be done",
      [&] {
        protocol::Message m = call_as(k, ep, "op", protocol::encode("status", {{"batch", batch}}));
        return batch_of(m.body, batch).at("state") == "done";
      }))
      << w.describe() << coord.child().describe();
  EXPECT_TRUE(shards_match_render(tmp / "out", job));

  // The operator key cancels a batch of its own.
  CliResult second = run_cli(
      tmp.path(), "submit-op2",
      cat({"submit", job.string(), "--out", (tmp / "out2").string()}, as_client(k, ep, "op")));
  ASSERT_EQ(second.status, 0) << second.err;
  const std::string batch2 = second.out.substr(0, second.out.find('\n'));
  CliResult cancel =
      run_cli(tmp.path(), "cancel-op", cat({"cancel", batch2}, as_client(k, ep, "op")));
  EXPECT_EQ(cancel.status, 0) << cancel.err;
  w.signal(SIGTERM);
  w.wait(30);
}

// Client keys after the secret in the coordinator's key file (the older form
// of the allow-list) are operators; everyone else is kept out.
TEST(FarmRoles, OlderKeyFileWithClientLinesLetsInOnlyThem) {
  TempDir tmp;
  const Keys k = make_keys(tmp, {"op"});
  const fs::path combined = tmp / "combined.key";
  write_text(combined, read_text(k.server_key) + k.pub("op") + "\n");
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 5,
                           {"--curve-secret", combined.string()});
  protocol::Message m = call_as(k, coord.endpoint(), "op", protocol::encode("status"));
  EXPECT_EQ(m.type, "status_reply") << m.body.dump();
  EXPECT_THROW(call_as(k, coord.endpoint(), std::nullopt, protocol::encode("status"), 1500),
               RuntimeError);
}

TEST(FarmRoles, BadAllowListStopsTheCoordinatorWithALocatedError) {
  TempDir tmp;
  const Keys k = make_keys(tmp, {"w1"});
  write_text(tmp / "clients.list", k.pub("w1") + " worker w1\n" + k.pub("w1") + " admin\n");
  CliResult r = run_cli(tmp.path(), "coordinator",
                        {"coordinator", "--listen", "tcp://127.0.0.1:*", "--state",
                         (tmp / "state").string(), "--curve-secret", k.server_key.string(),
                         "--curve-clients", (tmp / "clients.list").string()});
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find((tmp / "clients.list").string() + ":2:42"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("admin"), std::string::npos) << r.err;

  // A client key file that holds no key is bad input for the client too.
  write_text(tmp / "empty.key", "\n");
  CliResult c = run_cli(tmp.path(), "status",
                        {"status", "--coordinator", "tcp://127.0.0.1:1", "--curve-public",
                         k.server_pub.string(), "--curve-client", (tmp / "empty.key").string()});
  EXPECT_EQ(c.status, 2) << c.err;
  EXPECT_NE(c.err.find("empty.key"), std::string::npos) << c.err;
}

}  // namespace
}  // namespace dofarm::farm_testing
