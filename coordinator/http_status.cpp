#include "coordinator/http_status.h"

#include <arpa/inet.h>
#include <httplib.h>
#include <poll.h>
#include <sodium.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <fstream>
#include <map>
#include <mutex>
#include <thread>

#include "common/error.h"
#include "common/messages.h"
#include "common/protocol.h"
#include "coordinator/scheduler.h"
#include "coordinator/server.h"

namespace dofarm::coordinator {

namespace fs = std::filesystem;
using protocol::Json;

namespace {

constexpr size_t kMaxBodyBytes = 1024;          // GET needs none; more is 413
constexpr size_t kMaxRequestBytes = 64 * 1024;  // request line and headers of one request
constexpr double kRequestSeconds = 15;          // to read one request and write its answer
constexpr double kConnectionSeconds = 60;       // one connection, however many requests
constexpr size_t kRequestsPerConnection = 20;   // keep-alive requests on one connection
constexpr size_t kMaxTokenFileBytes = 4096;
constexpr size_t kMaxWantedBatches = 16;  // batches snapshotted for ?batch=
constexpr double kWatchSeconds = 30;      // snapshots are built this long after a request
constexpr double kWaitSeconds = 3;        // a request waits at most this for a fresh one
constexpr double kCostShare = 20;         // snapshots take at most ~1/20 of the loop

double steady_seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

SpecError bad_option(const std::string& option, const std::string& why) {
  return SpecError(FileLoc{}, option, why);
}

// httplib's task queue with a bound: a fixed set of threads, at most `max`
// connections waiting. When the queue is full the accepting thread serves
// the connection itself ("caller runs"), so a flood slows accepting (the
// kernel's backlog then refuses) instead of growing a queue.
class BoundedPool : public httplib::TaskQueue {
 public:
  BoundedPool(size_t threads, size_t max) : max_(max) {
    for (size_t i = 0; i < threads; ++i) threads_.emplace_back([this] { work(); });
  }
  void enqueue(std::function<void()> fn) override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!shutdown_ && jobs_.size() < max_) {
        jobs_.push_back(std::move(fn));
        cond_.notify_one();
        return;
      }
    }
    fn();
  }
  void shutdown() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      shutdown_ = true;
    }
    cond_.notify_all();
    for (std::thread& t : threads_) t.join();
    threads_.clear();
  }

 private:
  void work() {
    while (true) {
      std::function<void()> fn;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        cond_.wait(lock, [&] { return shutdown_ || !jobs_.empty(); });
        if (jobs_.empty()) return;  // shut down, nothing left to serve
        fn = std::move(jobs_.front());
        jobs_.pop_front();
      }
      fn();
    }
  }
  const size_t max_;
  std::mutex mutex_;
  std::condition_variable cond_;
  std::deque<std::function<void()>> jobs_;
  std::vector<std::thread> threads_;
  bool shutdown_ = false;
};

// A connection's socket as httplib reads and writes it, with bounds that
// httplib itself leaves open: the bytes of one request (so no number of
// header lines can grow the server), a deadline for each request and one
// for the connection (so a client that trickles bytes holds a thread for
// a bounded time), besides the timeout of each read and write.
class BoundedStream : public httplib::Stream {
 public:
  BoundedStream(int fd, double io_timeout, const std::atomic<bool>& stopping)
      : fd_(fd),
        io_ms_(int(io_timeout * 1000)),
        stopping_(stopping),
        connection_deadline_(steady_seconds() + kConnectionSeconds) {}
  // Starts the next request's budget and deadline.
  void begin_request() {
    read_bytes_ = 0;
    deadline_ = std::min(connection_deadline_, steady_seconds() + kRequestSeconds);
  }
  // A byte of another request is buffered or arrives within `ms`.
  bool wait_next(int ms) const { return begin_ < end_ || wait(POLLIN, ms); }

  bool is_readable() const override { return begin_ < end_ || wait(POLLIN, timeout_ms()); }
  bool is_writable() const override { return wait(POLLOUT, timeout_ms()); }
  ssize_t read(char* ptr, size_t size) override {
    if (begin_ == end_) {
      // GET and HEAD have no body: every byte read is request line or header.
      if (read_bytes_ >= kMaxRequestBytes || !wait(POLLIN, timeout_ms())) return -1;
      const ssize_t n = ::recv(fd_, buffer_, sizeof buffer_, 0);
      if (n <= 0) return n;
      read_bytes_ += size_t(n);
      begin_ = 0;
      end_ = size_t(n);
    }
    const size_t n = std::min(size, end_ - begin_);
    std::memcpy(ptr, buffer_ + begin_, n);
    begin_ += n;
    return ssize_t(n);
  }
  ssize_t write(const char* ptr, size_t size) override {
    if (!wait(POLLOUT, timeout_ms())) return -1;
    return ::send(fd_, ptr, size, MSG_NOSIGNAL);
  }
  void get_remote_ip_and_port(std::string& ip, int& port) const override {
    address(::getpeername, ip, port);
  }
  void get_local_ip_and_port(std::string& ip, int& port) const override {
    address(::getsockname, ip, port);
  }
  socket_t socket() const override { return fd_; }

 private:
  int timeout_ms() const {
    const double left = (deadline_ - steady_seconds()) * 1000;
    return int(std::clamp(left, 0.0, double(io_ms_)));
  }
  // Waits in slices, so a server that stops ends its connections soon.
  bool wait(short events, int ms) const {
    const double until = steady_seconds() + ms / 1000.0;
    while (!stopping_) {
      pollfd p{fd_, events, 0};
      const int slice = int(std::clamp((until - steady_seconds()) * 1000, 0.0, 100.0));
      const int r = ::poll(&p, 1, slice);
      if (r > 0) return (p.revents & events) != 0;
      if (r < 0 && errno != EINTR) return false;
      if (r == 0 && slice == 0) return false;
    }
    return false;
  }
  template <typename F>
  void address(F get, std::string& ip, int& port) const {
    sockaddr_storage a{};
    socklen_t len = sizeof a;
    ip.clear();
    port = 0;
    if (get(fd_, reinterpret_cast<sockaddr*>(&a), &len) != 0) return;
    char text[INET6_ADDRSTRLEN] = {};
    if (a.ss_family == AF_INET) {
      auto* v4 = reinterpret_cast<sockaddr_in*>(&a);
      inet_ntop(AF_INET, &v4->sin_addr, text, sizeof text);
      port = ntohs(v4->sin_port);
    } else if (a.ss_family == AF_INET6) {
      auto* v6 = reinterpret_cast<sockaddr_in6*>(&a);
      inet_ntop(AF_INET6, &v6->sin6_addr, text, sizeof text);
      port = ntohs(v6->sin6_port);
    }
    ip = text;
  }

  const int fd_;
  const int io_ms_;
  const std::atomic<bool>& stopping_;
  const double connection_deadline_;
  double deadline_ = 0;
  size_t read_bytes_ = 0;
  char buffer_[4096];
  size_t begin_ = 0, end_ = 0;
};

// httplib's server with its connection loop over a BoundedStream (it
// overrides the loop httplib declares virtual, and calls httplib's own
// request processing for each request).
class BoundedServer : public httplib::Server {
 public:
  double io_timeout = 2;
  std::atomic<bool> stopping{false};

 private:
  bool process_and_close_socket(socket_t sock) override {
    BoundedStream stream(sock, io_timeout, stopping);
    for (size_t n = 0; n < kRequestsPerConnection; ++n) {
      // The client has the keep-alive timeout to start its next request.
      if (n > 0 && !stream.wait_next(2000)) break;
      stream.begin_request();
      bool closed = false;
      const bool last = n + 1 == kRequestsPerConnection || !is_running();
      if (!process_request(stream, last, closed, nullptr) || closed) break;
    }
    ::shutdown(sock, SHUT_RDWR);
    ::close(sock);
    return true;
  }
};

// What HTTP threads serve, built on the coordinator's loop.
struct Snapshot {
  double built = 0;    // steady seconds
  std::string status;  // status_to_json() of the whole farm, as text
  std::string metrics;
  // Per asked batch: status_to_json() of status(batch) as text; empty when
  // the coordinator has no such batch.
  std::map<std::string, std::string> batches;
};

bool id_char(char c) {
  return std::isalnum(static_cast<unsigned char>(c)) || std::strchr("._:@+-", c);
}

}  // namespace

HttpAddress parse_http_address(const std::string& text) {
  const std::string option = "--http";
  const std::string example = " (expected HOST:PORT, e.g. 127.0.0.1:8080; got \"" + text + "\")";
  HttpAddress a;
  std::string port;
  if (!text.empty() && text[0] == '[') {
    const size_t close = text.find(']');
    if (close == std::string::npos || close + 1 >= text.size() || text[close + 1] != ':')
      throw bad_option(option, "an IPv6 address needs brackets and a port" + example);
    a.host = text.substr(1, close - 1);
    port = text.substr(close + 2);
  } else {
    const size_t colon = text.rfind(':');
    if (colon == std::string::npos || text.find(':') != colon)
      throw bad_option(option, "no port" + example);
    a.host = text.substr(0, colon);
    port = text.substr(colon + 1);
  }
  if (a.host.empty() || a.host.size() > 253) throw bad_option(option, "no host" + example);
  if (port.empty() || port.size() > 5 || !std::all_of(port.begin(), port.end(), ::isdigit) ||
      std::stoi(port) > 65535)
    throw bad_option(option, "the port must be 0..65535" + example);
  a.port = std::stoi(port);
  in_addr v4;
  in6_addr v6;
  if (inet_pton(AF_INET, a.host.c_str(), &v4) == 1)
    a.loopback = (ntohl(v4.s_addr) >> 24) == 127;
  else if (inet_pton(AF_INET6, a.host.c_str(), &v6) == 1)
    a.loopback = IN6_IS_ADDR_LOOPBACK(&v6);
  else
    a.loopback = a.host == "localhost";
  return a;
}

std::string load_http_token(const fs::path& file) {
  const FileLoc at{file.string()};
  struct stat st;
  if (::stat(file.c_str(), &st) != 0)
    throw SpecError(at, "http-token-file", std::string("cannot read it: ") + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) throw SpecError(at, "http-token-file", "not a regular file");
  if (st.st_mode & 077)
    throw SpecError(at, "http-token-file",
                    "readable by others; make it private: chmod 600 " + file.string());
  if (st.st_size > off_t(kMaxTokenFileBytes))
    throw SpecError(at, "http-token-file", "larger than 4 KiB; it holds one token line");
  std::ifstream in(file, std::ios::binary);
  std::string line;
  std::getline(in, line);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  if (line.size() < 16 || line.size() > 256)
    throw SpecError(FileLoc{file.string(), 1}, "http-token-file",
                    "the token must be 16..256 characters, got " + std::to_string(line.size()) +
                        " (make one: head -c 32 /dev/urandom | base64 > FILE)");
  for (char c : line)
    if (c <= ' ' || c > '~')
      throw SpecError(FileLoc{file.string(), 1}, "http-token-file",
                      "the token may hold printable ASCII without spaces only");
  return line;
}

std::string check_http_options(const HttpOptions& options) {
  const HttpAddress address = parse_http_address(options.address);
  std::string token;
  if (options.token_file) token = load_http_token(*options.token_file);
  if (!address.loopback && token.empty())
    throw bad_option("--http",
                     address.host +
                         " is not a loopback address: anyone who reaches it would see the farm. "
                         "Give --http-token-file FILE (docs/farm.md, \"Web page and metrics\")");
  return token;
}

bool token_matches(std::string_view given, std::string_view expected) {
  if (sodium_init() < 0) return false;
  // Hashing first makes the comparison independent of both lengths.
  unsigned char a[32], b[32];
  crypto_generichash(a, sizeof a, reinterpret_cast<const unsigned char*>(given.data()),
                     given.size(), nullptr, 0);
  crypto_generichash(b, sizeof b, reinterpret_cast<const unsigned char*>(expected.data()),
                     expected.size(), nullptr, 0);
  return sodium_memcmp(a, b, sizeof a) == 0;
}

struct HttpStatus::Impl {
  HttpOptions options;
  HttpAddress address;
  std::string token;  // empty: no token asked
  BoundedServer server;
  std::thread thread;
  int port = 0;

  std::mutex mutex;  // guards what follows
  std::condition_variable published;
  std::shared_ptr<const Snapshot> current;
  double last_asked = -1e30;
  std::map<std::string, double> wanted;  // batch -> when last asked
  double interval = 0.5;                 // between snapshots (grows with their cost)
  double last_try = -1e30;               // when tick() last built (or failed to)

  // The latest snapshot, waiting (bounded) for one fresh enough that holds
  // `batch` when given. Null when none came in time.
  std::shared_ptr<const Snapshot> fresh(const std::string* batch) {
    std::unique_lock<std::mutex> lock(mutex);
    const double now = steady_seconds();
    last_asked = now;
    if (batch) {
      wanted[*batch] = now;
      while (wanted.size() > kMaxWantedBatches) {
        auto oldest = std::min_element(wanted.begin(), wanted.end(),
                                       [](auto& x, auto& y) { return x.second < y.second; });
        wanted.erase(oldest);
      }
    }
    const double max_age = interval + 1.5;
    published.wait_for(lock, std::chrono::duration<double>(kWaitSeconds), [&] {
      return current && steady_seconds() - current->built <= max_age &&
             (!batch || current->batches.count(*batch));
    });
    if (current && batch && !current->batches.count(*batch)) return nullptr;
    return current;
  }

  bool authorized(const httplib::Request& req) const {
    if (token.empty()) return true;
    const std::string auth = req.get_header_value("Authorization");
    const std::string bearer = "Bearer ";
    if (auth.size() > bearer.size() && auth.compare(0, bearer.size(), bearer) == 0)
      return token_matches(std::string_view(auth).substr(bearer.size()), token);
    if (req.has_param("token")) return token_matches(req.get_param_value("token"), token);
    return false;
  }

  void routes() {
    server.set_default_headers({{"X-Content-Type-Options", "nosniff"},
                                {"Cache-Control", "no-store"},
                                {"Referrer-Policy", "no-referrer"},
                                {"X-Frame-Options", "DENY"}});
    server.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
      if (req.method != "GET" && req.method != "HEAD") {
        res.status = 405;
        res.set_header("Allow", "GET, HEAD");
        res.set_content("read-only: GET and HEAD only\n", "text/plain");
        return httplib::Server::HandlerResponse::Handled;
      }
      // A body (GET and HEAD need none) is refused before it is read.
      if (req.get_header_value_count("Transfer-Encoding") > 0 ||
          req.get_header_value<uint64_t>("Content-Length") > kMaxBodyBytes) {
        res.status = 413;
        res.set_header("Connection", "close");
        res.set_content("a request body is not taken here\n", "text/plain");
        return httplib::Server::HandlerResponse::Handled;
      }
      if (!authorized(req)) {
        res.status = 401;
        res.set_header("WWW-Authenticate", "Bearer realm=\"dofarm\"");
        res.set_content(
            "an access token is needed: header \"Authorization: Bearer TOKEN\" or ?token=TOKEN\n",
            "text/plain");
        return httplib::Server::HandlerResponse::Handled;
      }
      return httplib::Server::HandlerResponse::Unhandled;
    });
    server.Get("/", [](const httplib::Request&, httplib::Response& res) {
      res.set_header("Content-Security-Policy", status_page_csp());
      res.set_content(status_page_html(), "text/html; charset=utf-8");
    });
    server.Get("/api/status", [this](const httplib::Request& req, httplib::Response& res) {
      std::string batch;
      const bool one = req.has_param("batch");
      if (one) {
        batch = req.get_param_value("batch");
        if (batch.empty() || batch.size() > protocol::kMaxIdBytes ||
            !std::all_of(batch.begin(), batch.end(), id_char)) {
          res.status = 400;
          res.set_content(Json{{"error", "batch: not a batch id"}}.dump() + "\n",
                          "application/json");
          return;
        }
      }
      std::shared_ptr<const Snapshot> s = fresh(one ? &batch : nullptr);
      if (!s) {
        res.status = 503;
        res.set_header("Retry-After", "2");
        res.set_content(Json{{"error", "the coordinator is busy; try again"}}.dump() + "\n",
                        "application/json");
        return;
      }
      if (one) {
        const std::string& text = s->batches.at(batch);
        if (text.empty()) {
          res.status = 404;
          res.set_content(
              Json{{"error", "no batch " + batch + " on this coordinator"}}.dump() + "\n",
              "application/json");
          return;
        }
        res.set_content(text, "application/json");
        return;
      }
      res.set_content(s->status, "application/json");
    });
    server.Get("/metrics", [this](const httplib::Request&, httplib::Response& res) {
      std::shared_ptr<const Snapshot> s = fresh(nullptr);
      if (!s) {
        res.status = 503;
        res.set_header("Retry-After", "2");
        res.set_content("the coordinator is busy; try again\n", "text/plain");
        return;
      }
      res.set_content(s->metrics, "text/plain; version=0.0.4; charset=utf-8");
    });
    server.set_error_handler(
        httplib::Server::HandlerWithResponse([](const httplib::Request&, httplib::Response& res) {
          if (!res.body.empty()) return httplib::Server::HandlerResponse::Unhandled;
          res.set_content("HTTP " + std::to_string(res.status) + "\n", "text/plain");
          return httplib::Server::HandlerResponse::Handled;
        }));
    server.set_exception_handler(
        [](const httplib::Request&, httplib::Response& res, std::exception_ptr) {
          res.status = 500;
          res.set_content("internal error\n", "text/plain");
        });
  }
};

HttpStatus::HttpStatus(const HttpOptions& options) : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.options = options;
  m.interval = options.min_interval_seconds;
  m.token = check_http_options(options);
  m.address = parse_http_address(options.address);
  const size_t threads = size_t(std::clamp(options.threads, 1, 64));
  const size_t queue = size_t(std::clamp(options.queue, 0, 1024));
  m.server.new_task_queue = [threads, queue] { return new BoundedPool(threads, queue); };
  m.server.io_timeout = options.io_timeout_seconds;
  const auto io = std::chrono::duration<double>(options.io_timeout_seconds);
  m.server.set_read_timeout(std::chrono::duration_cast<std::chrono::microseconds>(io));
  m.server.set_write_timeout(std::chrono::duration_cast<std::chrono::microseconds>(io));
  m.server.set_keep_alive_timeout(2);
  m.server.set_keep_alive_max_count(100);
  m.server.set_payload_max_length(kMaxBodyBytes);
  m.routes();
  if (m.address.port == 0) {
    m.port = m.server.bind_to_any_port(m.address.host);
  } else {
    m.port = m.server.bind_to_port(m.address.host, m.address.port) ? m.address.port : -1;
  }
  if (m.port <= 0)
    throw RuntimeError("--http " + options.address + ": cannot listen there (" +
                       std::strerror(errno) + "; another process on that port?)");
  m.thread = std::thread([&m] { m.server.listen_after_bind(); });
  // stop() only stops a server that runs: wait until it does.
  for (int i = 0; i < 5000 && !m.server.is_running(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  spdlog::info("web page and metrics on {}{}", url(), m.token.empty() ? "" : " (token needed)");
}

HttpStatus::~HttpStatus() {
  impl_->server.stopping = true;
  impl_->server.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

std::string HttpStatus::url() const {
  const std::string& h = impl_->address.host;
  const bool v6 = h.find(':') != std::string::npos;
  return "http://" + (v6 ? "[" + h + "]" : h) + ":" + std::to_string(impl_->port) + "/";
}

void HttpStatus::tick(Scheduler& scheduler, const ServerCounters& counters) {
  Impl& m = *impl_;
  std::vector<std::string> batches;
  {
    std::lock_guard<std::mutex> lock(m.mutex);
    const double now = steady_seconds();
    if (now - m.last_asked > kWatchSeconds) return;  // nobody watches: no work
    if (now - m.last_try < m.interval) return;
    m.last_try = now;
    std::erase_if(m.wanted, [&](const auto& w) { return now - w.second > kWatchSeconds; });
    for (const auto& [id, when] : m.wanted) batches.push_back(id);
  }
  try {
    const double t0 = steady_seconds();
    auto s = std::make_shared<Snapshot>();
    const Json status = status_to_json(scheduler.status(""));
    s->status = status.dump(2) + "\n";
    for (const std::string& id : batches) {
      // A batch's page draws its frames from the task list: the data of
      // `status BATCH --tasks --json`.
      StatusQuery q;
      q.batch = id;
      q.tasks = true;
      const StatusReport r = scheduler.status(q);
      s->batches[id] = r.batches.empty() ? "" : status_to_json(r).dump(2) + "\n";
    }
    const double cost = steady_seconds() - t0;
    s->metrics = metrics_text(status, counters, cost);
    s->built = steady_seconds();
    std::lock_guard<std::mutex> lock(m.mutex);
    m.interval = std::max(m.options.min_interval_seconds, kCostShare * cost);
    m.current = std::move(s);
    m.published.notify_all();
  } catch (const std::exception& e) {
    spdlog::error("building the web status failed: {}", e.what());
  }
}

}  // namespace dofarm::coordinator
