// The coordinator's web face (--http; docs/farm.md "Web page and metrics")
// with a real coordinator and real workers on loopback: /api/status is the
// data `dofarm status --json` prints, /metrics is well-formed Prometheus
// text whose numbers are those of the status and of what the test itself
// sent, a non-loopback bind needs its token, oversized requests are refused
// while the farm goes on, and the page, opened by a real browser (Debian's
// chromium, headless), shows the numbers of `status --json` and follows a
// running batch.
#include <arpa/inet.h>
#include <httplib.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <regex>

#include "common/job_snapshot.h"
#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

// The web page's port, from the coordinator's second line "web http://HOST:PORT/".
int web_port(Child& coordinator) {
  const std::regex line("\nweb http://[^\n]*:([0-9]+)/\n");
  int port = 0;
  EXPECT_TRUE(poll_until("the coordinator's web address", [&] {
    std::smatch m;
    const std::string out = coordinator.out();
    if (!std::regex_search(out, m, line)) return false;
    port = std::stoi(m[1]);
    return true;
  })) << coordinator.describe();
  return port;
}

httplib::Headers bearer(const std::string& token) {
  if (token.empty()) return {};
  return {{"Authorization", "Bearer " + token}};
}

// GET on 127.0.0.1:port; status -1 when no answer came.
struct HttpResult {
  int status = -1;
  std::string body, content_type;
};
HttpResult http_get(int port, const std::string& path, const httplib::Headers& headers = {}) {
  httplib::Client client("127.0.0.1", port);
  client.set_connection_timeout(10);
  client.set_read_timeout(10);
  HttpResult r;
  if (auto res = client.Get(path, headers)) {
    r.status = res->status;
    r.body = res->body;
    r.content_type = res->get_header_value("Content-Type");
  }
  return r;
}

Json api_json(int port, const std::string& path) {
  HttpResult r = http_get(port, path);
  if (r.status != 200)
    throw RuntimeError(path + ": HTTP " + std::to_string(r.status) + " " + r.body);
  return Json::parse(r.body);
}

// The API's answer taken no earlier than `at` (coordinator clock): the
// loop publishes snapshots, so a request may see one a moment old.
Json api_status_since(int port, const std::string& path, double at) {
  Json j;
  EXPECT_TRUE(poll_until("a snapshot newer than the CLI's status", [&] {
    j = api_json(port, path);
    return j.at("now").get<double>() >= at;
  }));
  return j;
}

// `dofarm status --json` or `dofarm status BATCH --tasks --json` (what
// /api/status?batch=BATCH serves), run as a user runs it.
Json cli_status(const TempDir& tmp, const std::string& endpoint, const std::string& batch = "") {
  std::vector<std::string> args = {"status"};
  if (!batch.empty()) args.insert(args.end(), {batch, "--tasks"});
  args.insert(args.end(), {"--coordinator", endpoint, "--json"});
  CliResult r = run_cli(tmp.path(), "status_json", args);
  EXPECT_EQ(r.status, 0) << r.err;
  return Json::parse(r.out);
}

// Two status reports taken at different times of a farm that stood still
// are the same data: everything equal except `now` and what is computed
// from it. frames/hour is (frames rendered within the rate window) * 3600
// / (now - window start) (coordinator/scheduler_report.cpp), so that
// product must agree; ETA and stall time must be there in both or neither.
::testing::AssertionResult same_status(Json a, Json b, double rate_window = 600) {
  for (Json* j : {&a, &b}) {
    const double now = j->at("now").get<double>();
    for (Json& batch : j->at("batches")) {
      const double start = std::max(now - rate_window, batch.at("created").get<double>());
      batch["frames_in_window"] =
          std::llround(batch.at("frames_per_hour").get<double>() * (now - start) / 3600.0);
      for (const char* k : {"eta_seconds", "stalled_seconds"})
        batch[k] = batch.at(k).is_null() ? "absent" : "present";
      batch.erase("frames_per_hour");
    }
    // A worker's heartbeat age is `now` minus its last_seen.
    for (Json& w : j->at("workers")) {
      const double age = w.at("heartbeat_age").get<double>();
      const double expected = std::max(0.0, now - w.at("last_seen").get<double>());
      w["heartbeat_age"] = std::abs(age - expected) < 1e-6 ? "now - last_seen" : "inconsistent";
    }
    j->erase("now");
  }
  if (a == b) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "API:\n"
                                       << a.dump(1) << "\nstatus --json:\n"
                                       << b.dump(1);
}

// Prometheus text format 0.0.4: every line a comment (# HELP / # TYPE) or
// `name{label="value",...} number`; a family's TYPE before its samples.
// Returns the samples by their full name with labels; a parse failure fails
// the test naming the line.
std::map<std::string, double> parse_metrics(const std::string& text) {
  const std::string label = R"([a-zA-Z_][a-zA-Z0-9_]*="(?:[^"\\\n]|\\.)*")";
  const std::regex sample("([a-zA-Z_:][a-zA-Z0-9_:]*)(\\{" + label + "(?:," + label +
                          ")*\\})? ([-+0-9.eE]+|NaN|[+-]Inf)");
  const std::regex type(
      "# TYPE ([a-zA-Z_:][a-zA-Z0-9_:]*) (counter|gauge|histogram|summary|untyped)");
  const std::regex help("# HELP ([a-zA-Z_:][a-zA-Z0-9_:]*) .+");
  std::map<std::string, double> out;
  std::map<std::string, std::string> types;
  std::istringstream in(text);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    std::smatch m;
    if (std::regex_match(line, m, type)) {
      EXPECT_FALSE(types.count(m[1])) << "line " << n << ": second TYPE of " << m[1];
      types[m[1]] = m[2];
      continue;
    }
    if (std::regex_match(line, m, help)) continue;
    if (!std::regex_match(line, m, sample)) {
      ADD_FAILURE() << "line " << n << " is not a sample: \"" << line << "\"";
      continue;
    }
    EXPECT_TRUE(types.count(m[1])) << "line " << n << ": " << m[1] << " has no TYPE before it";
    if (types[m[1]] == "counter") {
      EXPECT_TRUE(m[1].str().size() > 6 && m[1].str().ends_with("_total")) << m[1];
    }
    const std::string key = m[1].str() + m[2].str();
    EXPECT_FALSE(out.count(key)) << "line " << n << ": " << key << " twice";
    out[key] = std::stod(m[3]);
  }
  return out;
}

double metric(const std::map<std::string, double>& m, const std::string& key) {
  auto it = m.find(key);
  if (it == m.end()) {
    ADD_FAILURE() << "no sample " << key;
    return -1;
  }
  return it->second;
}

// Every number of a batch in /metrics is the one of the status report.
void expect_metrics_match(const std::map<std::string, double>& m, const Json& status) {
  for (const Json& b : status.at("batches")) {
    const std::string id = "batch=\"" + b.at("batch").get<std::string>() + "\"";
    for (const auto& [state, key] : {std::pair{"pending", "tasks_pending"},
                                     {"running", "tasks_leased"},
                                     {"done", "tasks_done"},
                                     {"failed", "tasks_failed"}})
      EXPECT_EQ(metric(m, "dofarm_tasks{" + id + ",state=\"" + state + "\"}"),
                b.at(key).get<double>())
          << id << " " << state;
    EXPECT_EQ(metric(m, "dofarm_batch_frames{" + id + "}"), b.at("frames_total").get<double>());
    EXPECT_EQ(metric(m, "dofarm_frames_rendered{" + id + "}"),
              b.at("frames_rendered").get<double>());
    EXPECT_EQ(metric(m, "dofarm_frames_packed{" + id + "}"), b.at("frames_packed").get<double>());
    EXPECT_EQ(metric(m, "dofarm_batch_state{" + id + ",state=\"" +
                            b.at("state").get<std::string>() + "\"}"),
              1.0);
  }
  int live = 0;
  for (const Json& w : status.at("workers")) live += w.at("live").get<bool>();
  EXPECT_EQ(metric(m, "dofarm_workers_live"), live);
  EXPECT_EQ(metric(m, "dofarm_workers"), double(status.at("workers").size()));
}

int count_of(const std::string& text, const std::string& what) {
  int n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

TEST(FarmHttp, ApiStatusIsTheDataOfStatusJsonAndMetricsCountTheSame) {
  TempDir tmp;
  TinyJob big;  // 12 frames of 4 tiles and 3 packs: a worker can be stopped halfway
  big.frame_end = 11;
  big.per_shard = 4;
  big.reference_spp = 16;
  const fs::path spec = write_job(tmp.path(), "job.toml", big);
  // Lease 2 s: a stopped worker's lease expires soon, and after two leases
  // it no longer counts as live; from then on the farm stands still.
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 2, {"--http", "127.0.0.1:0"});
  const std::string ep = coord.endpoint();
  const int port = web_port(coord.child());
  ASSERT_GT(port, 0);
  int status_calls = 0;  // `status` messages this test sends
  auto status_of = [&](const std::string& batch) {
    ++status_calls;
    return farm_status(ep, batch);
  };

  CliResult sub =
      run_cli(tmp.path(), "submit",
              {"submit", spec.string(), "--coordinator", ep, "--out", (tmp / "out").string()});
  ASSERT_EQ(sub.status, 0) << sub.err;
  const std::string batch = sub.out.substr(0, sub.out.find('\n'));

  Child w = start_worker(tmp.path(), ep, "w1");
  ASSERT_TRUE(poll_until("two tasks done", [&] {
    return batch_of(status_of(batch), batch).at("tasks_done").get<int>() >= 2;
  })) << coord.child().describe();
  w.signal(SIGSTOP);
  // Still from the moment the coordinator also noticed that the batch has
  // no eligible worker (it looks once a second).
  ASSERT_TRUE(poll_until("the stopped worker to lose its lease and count as gone", [&] {
    Json st = status_of("");
    const Json b = batch_of(st, batch);
    return !st.at("workers").at(0).at("live").get<bool>() && b.at("tasks_leased").get<int>() == 0 &&
           !b.at("stalled_seconds").is_null();
  }));

  // Halfway: the batch runs, some tasks done, none leased.
  Json cli = cli_status(tmp, ep, batch);
  ++status_calls;
  Json api = api_status_since(port, "/api/status?batch=" + batch, cli.at("now").get<double>());
  ASSERT_EQ(api.at("batches").size(), 1u);
  EXPECT_EQ(api["batches"][0].at("state"), "running");
  EXPECT_LT(api["batches"][0].at("tasks_done").get<int>(),
            api["batches"][0].at("tasks_total").get<int>());
  EXPECT_TRUE(same_status(api, cli));
  Json cli_all = cli_status(tmp, ep);
  ++status_calls;
  Json api_all = api_status_since(port, "/api/status", cli_all.at("now").get<double>());
  EXPECT_TRUE(same_status(api_all, cli_all));

  // /metrics: the same numbers, and the counters of what happened: this
  // test's status calls, one submit, the leases that expired (each logged).
  std::map<std::string, double> m;
  ASSERT_TRUE(poll_until("/metrics to count every status call", [&] {
    HttpResult r = http_get(port, "/metrics");
    if (r.status != 200) return false;
    EXPECT_EQ(r.content_type, "text/plain; version=0.0.4; charset=utf-8");
    m = parse_metrics(r.body);
    return m["dofarm_messages_received_total{type=\"status\"}"] >= status_calls;
  }));
  EXPECT_EQ(metric(m, "dofarm_messages_received_total{type=\"status\"}"), status_calls);
  EXPECT_EQ(metric(m, "dofarm_messages_received_total{type=\"submit\"}"), 1);
  EXPECT_GE(metric(m, "dofarm_messages_received_total{type=\"done\"}"),
            api_all["batches"][0].at("tasks_done").get<double>());
  EXPECT_GE(metric(m, "dofarm_messages_received_total{type=\"request\"}"), 1);
  EXPECT_EQ(metric(m, "dofarm_lease_expiries_total"),
            count_of(coord.child().err(), "lease expired, requeued"));
  EXPECT_EQ(metric(m, "dofarm_task_failures_total"), 0);
  EXPECT_EQ(metric(m, "dofarm_batches{state=\"running\"}"), 1);
  expect_metrics_match(m, api_all);

  // To the end; the worker killed (no goodbye), so it stops counting as
  // live two leases after it was last seen.
  w.signal(SIGCONT);
  ASSERT_TRUE(poll_until("the batch to finish", [&] { return batch_state(ep, batch) == "done"; }));
  w.kill9();
  ASSERT_TRUE(poll_until("the killed worker to count as gone", [&] {
    return !farm_status(ep).at("workers").at(0).at("live").get<bool>();
  }));
  cli = cli_status(tmp, ep, batch);
  api = api_status_since(port, "/api/status?batch=" + batch, cli.at("now").get<double>());
  EXPECT_EQ(api["batches"][0].at("frames_packed"), 12);
  EXPECT_TRUE(same_status(api, cli));
  HttpResult metrics = http_get(port, "/metrics");
  ASSERT_EQ(metrics.status, 200);
  expect_metrics_match(parse_metrics(metrics.body), api);

  // A batch that does not exist, and one that cannot be an id.
  HttpResult none = http_get(port, "/api/status?batch=b-nope");
  EXPECT_EQ(none.status, 404);
  EXPECT_NE(none.body.find("no batch b-nope"), std::string::npos) << none.body;
  EXPECT_EQ(http_get(port, "/api/status?batch=%22%3E%3Cscript%3E").status, 400);
  EXPECT_EQ(http_get(port, "/nothing-here").status, 404);
}

std::string find_browser();
std::string dump_dom(const std::string& browser, const TempDir& tmp, const std::string& url,
                     const std::string& name);
int refreshes(const std::string& dom);

TEST(FarmHttp, NonLoopbackBindNeedsItsTokenAndEveryRequestMustCarryIt) {
  TempDir tmp;
  // No token: refused before anything is written.
  CliResult r = run_cli(tmp.path(), "no_token",
                        {"coordinator", "--listen", "tcp://127.0.0.1:*", "--state",
                         (tmp / "state").string(), "--http", "0.0.0.0:0"});
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("--http-token-file"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(tmp / "state"));

  const std::string token = "s3cret-Token-0123456789abcdef";
  const fs::path token_file = tmp / "http.token";
  write_text(token_file, token + "\n");
  ::chmod(token_file.c_str(), 0644);  // others may read it: refused
  r = run_cli(tmp.path(), "open_token",
              {"coordinator", "--listen", "tcp://127.0.0.1:*", "--state", (tmp / "state").string(),
               "--http", "0.0.0.0:0", "--http-token-file", token_file.string()});
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("chmod 600"), std::string::npos) << r.err;
  ::chmod(token_file.c_str(), 0600);

  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 30,
                           {"--http", "0.0.0.0:0", "--http-token-file", token_file.string()});
  const int port = web_port(coord.child());
  for (const char* path : {"/", "/api/status", "/metrics"}) {
    EXPECT_EQ(http_get(port, path).status, 401) << path;
    EXPECT_EQ(http_get(port, path, bearer(token + "x")).status, 401) << path;
    EXPECT_EQ(http_get(port, path, bearer(token.substr(1))).status, 401) << path;
    EXPECT_EQ(http_get(port, path, {{"Authorization", "Basic " + token}}).status, 401) << path;
    EXPECT_EQ(http_get(port, std::string(path) + "?token=wrong-token-0123456789").status, 401);
    EXPECT_EQ(http_get(port, path, bearer(token)).status, 200) << path;
    EXPECT_EQ(http_get(port, std::string(path) + "?token=" + token).status, 200) << path;
  }
  HttpResult page = http_get(port, "/", bearer(token));
  EXPECT_NE(page.body.find("<title>dofarm</title>"), std::string::npos);
  EXPECT_EQ(page.content_type, "text/html; charset=utf-8");
  // The page opened with ?token= sends it with each of its own requests.
  if (const std::string browser = find_browser(); !browser.empty()) {
    const std::string url = "http://127.0.0.1:" + std::to_string(port) + "/?token=" + token;
    EXPECT_GE(refreshes(dump_dom(browser, tmp, url, "token")), 2);
  }
}

// Sends `request` on a fresh connection to 127.0.0.1:port and returns the
// status code of the answer, 0 when the server closed without one.
int raw_request(int port, const std::string& request) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(uint16_t(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  timeval tv{10, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  // The server may refuse and close before it has read everything.
  for (size_t sent = 0; sent < request.size();) {
    const ssize_t n = ::send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) break;
    sent += size_t(n);
  }
  char buf[64] = {};
  const ssize_t n = ::recv(fd, buf, sizeof buf - 1, 0);
  ::close(fd);
  int code = 0;
  if (n > 12 && std::sscanf(buf, "HTTP/1.1 %d", &code) == 1) return code;
  return 0;
}

TEST(FarmHttp, OversizedRequestsAreRefusedAndTheFarmGoesOn) {
  TempDir tmp;
  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 30, {"--http", "127.0.0.1:0"});
  const int port = web_port(coord.child());
  const std::string host = "Host: 127.0.0.1\r\n";
  // A 100 KB request line; one 100 KB header; 200,000 small headers (2.6 MB).
  auto refused = [](int code) { return code == 0 || code == 400 || code == 414 || code == 431; };
  int code =
      raw_request(port, "GET /" + std::string(100000, 'a') + " HTTP/1.1\r\n" + host + "\r\n");
  EXPECT_TRUE(refused(code)) << code;
  code = raw_request(
      port, "GET / HTTP/1.1\r\n" + host + "X-Big: " + std::string(100000, 'b') + "\r\n\r\n");
  EXPECT_TRUE(refused(code)) << code;
  std::string many = "GET / HTTP/1.1\r\n" + host;
  for (int i = 0; i < 200000; ++i) many += "X-" + std::to_string(i) + ": 1\r\n";
  code = raw_request(port, many + "\r\n");
  EXPECT_TRUE(refused(code)) << code;
  // A body (announced as 100 MB) is refused before it is read; other methods too.
  EXPECT_EQ(raw_request(port, "GET /api/status HTTP/1.1\r\n" + host +
                                  "Content-Length: 100000000\r\n\r\n" + std::string(4096, 'c')),
            413);
  EXPECT_EQ(raw_request(
                port, "GET /api/status HTTP/1.1\r\n" + host + "Transfer-Encoding: chunked\r\n\r\n"),
            413);
  EXPECT_EQ(
      raw_request(port, "POST /api/status HTTP/1.1\r\n" + host + "Content-Length: 2\r\n\r\n{}"),
      405);
  EXPECT_EQ(raw_request(port, "DELETE /api/status HTTP/1.1\r\n" + host + "\r\n"), 405);

  // More connections that send nothing than there are HTTP threads and
  // queue places: the coordinator's own loop answers all the same, and
  // HTTP does again once they are gone.
  std::vector<int> idle;
  for (int i = 0; i < 24; ++i) {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(uint16_t(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0)
      idle.push_back(fd);
    else
      ::close(fd);
  }
  EXPECT_NO_THROW(farm_status(coord.endpoint()));
  for (int fd : idle) ::close(fd);
  EXPECT_TRUE(poll_until("HTTP to answer again",
                         [&] { return http_get(port, "/api/status").status == 200; }));
  EXPECT_TRUE(coord.child().running());
}

// --- the page in a real browser ---------------------------------------------

std::string find_browser() {
  for (const char* b : {"/usr/bin/chromium", "/usr/bin/chromium-browser"})
    if (fs::exists(b)) return b;
  return "";
}

// The DOM after the page ran for 3.5 s of the browser's virtual time (it
// refreshes every 1.5 s: three times).
std::string dump_dom(const std::string& browser, const TempDir& tmp, const std::string& url,
                     const std::string& name) {
  const fs::path dom = tmp / (name + ".html");
  const std::string cmd = browser +
                          " --headless --no-sandbox --disable-gpu --disable-dev-shm-usage "
                          "--no-first-run --user-data-dir=" +
                          (tmp / ("profile-" + name)).string() +
                          " --virtual-time-budget=3500 --dump-dom '" + url + "' > " + dom.string() +
                          " 2>" + (tmp / (name + ".err")).string();
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
  return read_text(dom);
}

// Text as the browser serialises a text node.
std::string html_text(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '&')
      out += "&amp;";
    else if (c == '<')
      out += "&lt;";
    else if (c == '>')
      out += "&gt;";
    else
      out += c;
  }
  return out;
}

// The element `<tag ATTR ...>...</tag>` that starts with `open` (the first
// one), or "" when the page has none.
std::string element(const std::string& dom, const std::string& open, const std::string& tag) {
  const size_t at = dom.find(open);
  if (at == std::string::npos) return "";
  const size_t end = dom.find("</" + tag + ">", at);
  return dom.substr(at, end == std::string::npos ? std::string::npos : end - at);
}

// The text of the cell data-field="FIELD" in `row`.
std::string field(const std::string& row, const std::string& name) {
  const std::regex cell("data-field=\"" + name + "\"[^>]*>(?:<code>)?([^<]*)<");
  std::smatch m;
  return std::regex_search(row, m, cell) ? m[1].str() : "(no " + name + ")";
}

// Every batch of `status` appears in the page with the same numbers.
void expect_page_shows(const std::string& dom, const Json& status) {
  for (const Json& b : status.at("batches")) {
    const std::string id = b.at("batch");
    const std::string row = element(dom, "<tr data-batch=\"" + id + "\"", "tr");
    ASSERT_FALSE(row.empty()) << id << " not on the page";
    EXPECT_EQ(field(row, "state"), b.at("state").get<std::string>()) << id;
    for (const char* k :
         {"priority", "frames_rendered", "frames_packed", "frames_total", "tasks_done",
          "tasks_leased", "tasks_pending", "tasks_failed", "tasks_total"})
      EXPECT_EQ(field(row, k), std::to_string(b.at(k).get<int>())) << id << " " << k;
  }
  int live = 0;
  for (const Json& w : status.at("workers")) {
    live += w.at("live").get<bool>();
    const std::string row =
        element(dom, "<tr data-worker=\"" + w.at("worker").get<std::string>() + "\"", "tr");
    ASSERT_FALSE(row.empty()) << w.at("worker") << " not on the page";
    EXPECT_EQ(field(row, "live"), w.at("live").get<bool>() ? "true" : "false");
  }
  EXPECT_NE(dom.find("<span id=\"workers-live\">" + std::to_string(live) + "</span>"),
            std::string::npos);
}

// Polls until two status reports 0.3 s apart are the same data (a stopped
// worker's last messages have arrived): the farm stands still.
::testing::AssertionResult wait_still(const std::string& endpoint) {
  Json before = farm_status(endpoint);
  return poll_until("the farm to stand still", [&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    Json now = farm_status(endpoint);
    const bool still = same_status(now, before);
    before = now;
    return still;
  });
}

int refreshes(const std::string& dom) {
  std::smatch m;
  return std::regex_search(dom, m, std::regex("data-refreshes=\"([0-9]+)\"")) ? std::stoi(m[1]) : 0;
}

TEST(FarmHttp, PageInABrowserShowsTheNumbersOfStatusJsonAndFollowsARunningBatch) {
  const std::string browser = find_browser();
  if (browser.empty()) GTEST_SKIP() << "no chromium (scripts/install-deps.sh installs it)";
  TempDir tmp;
  // A batch whose one task cannot succeed (its job copy vanished), so the
  // page has a failure with its error and reproduce command to show.
  fs::create_directories(tmp / "scene");
  fs::copy_file(cornell_scene(), tmp / "scene" / "cornell.gltf");
  fs::copy_file(cornell_scene().parent_path() / "cornell.bin", tmp / "scene" / "cornell.bin");
  TinyJob doomed;
  doomed.scene = tmp / "scene" / "cornell.gltf";
  doomed.tile = 32;
  doomed.frame_end = 0;
  TinyJob healthy;  // 24 frames of 4 tiles: long enough to look at while it runs
  healthy.frame_end = 23;
  healthy.per_shard = 4;
  healthy.reference_spp = 32;

  CoordinatorProcess coord(tmp.path(), "coordinator", tmp / "state", 60, {"--http", "127.0.0.1:0"});
  const std::string ep = coord.endpoint();
  const int port = web_port(coord.child());
  auto submit = [&](const TinyJob& j, const std::string& name) {
    const fs::path spec = write_job(tmp.path(), name + ".toml", j);
    CliResult r =
        run_cli(tmp.path(), "submit_" + name,
                {"submit", spec.string(), "--coordinator", ep, "--out", (tmp / name).string()});
    EXPECT_EQ(r.status, 0) << r.err;
    return r.out.substr(0, r.out.find('\n'));
  };
  const std::string bad = submit(doomed, "doomed");
  ASSERT_TRUE(fs::remove(job_dir(tmp / "doomed", read_output_owner(tmp / "doomed")->job) / "files" /
                         "cornell.gltf"));
  Child w1 = start_worker(tmp.path(), ep, "w1");
  Child w2 = start_worker(tmp.path(), ep, "w2");
  Child w3 = start_worker(tmp.path(), ep, "w3");
  ASSERT_TRUE(poll_until("the doomed batch to fail", [&] {
    return batch_state(ep, bad) == "failed";
  })) << coord.child().describe();
  // w2 and w3 go (they still count as live for two leases); w1 stands still
  // while the healthy batch is submitted: the farm holds still.
  w2.kill9();
  w3.kill9();
  w1.signal(SIGSTOP);
  const std::string good = submit(healthy, "healthy");
  ASSERT_TRUE(wait_still(ep));

  // Load 1, showing the failed batch in detail (?batch=).
  Json a = cli_status(tmp, ep);
  api_status_since(port, "/api/status", a.at("now").get<double>());
  const std::string url = "http://127.0.0.1:" + std::to_string(port) + "/";
  const std::string dom_a = dump_dom(browser, tmp, url + "?batch=" + bad, "a");
  EXPECT_GE(refreshes(dom_a), 2) << "the page did not refresh itself";
  expect_page_shows(dom_a, a);
  // Its failed tasks (the tile, and the pack that waited for it), each with
  // its error and, for the tile, the command that reproduces it.
  const Json failed = batch_of(a, bad).at("failed");
  ASSERT_FALSE(failed.empty());
  bool reproduced = false;
  for (const Json& f : failed) {
    const std::string row = element(dom_a, "<tr data-task=\"" + f.at("task").dump() + "\"", "tr");
    ASSERT_FALSE(row.empty()) << "failed task " << f.at("task") << " is not on the page";
    EXPECT_EQ(field(row, "error"), html_text(f.at("error")));
    EXPECT_EQ(field(row, "reproduce"), html_text(f.at("reproduce")));
    reproduced |= f.at("reproduce").get<std::string>().find("dofarm render") == 0;
  }
  EXPECT_TRUE(reproduced) << failed.dump(1);
  // The healthy batch runs a while, then the farm holds still again.
  const int done_a = batch_of(a, good).at("tasks_done");
  w1.signal(SIGCONT);
  ASSERT_TRUE(poll_until("some tasks of the healthy batch done", [&] {
    return batch_of(farm_status(ep, good), good).at("tasks_done").get<int>() >= done_a + 4;
  }));
  w1.signal(SIGSTOP);
  ASSERT_TRUE(wait_still(ep));
  Json b = cli_status(tmp, ep);
  api_status_since(port, "/api/status", b.at("now").get<double>());
  const std::string dom_b = dump_dom(browser, tmp, url, "b");
  EXPECT_GE(refreshes(dom_b), 2);
  expect_page_shows(dom_b, b);
  EXPECT_EQ(batch_of(b, good).at("state"), "running");
  EXPECT_GT(batch_of(b, good).at("tasks_done").get<int>(), done_a);
  // Without ?batch= the page shows the running batch in detail.
  EXPECT_NE(dom_b.find("<span id=\"detail-id\">" + good + " (running)</span>"), std::string::npos);
  w1.signal(SIGCONT);
}

}  // namespace
}  // namespace dofarm::farm_testing
