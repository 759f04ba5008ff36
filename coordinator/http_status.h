// The coordinator's read-only web face (docs/farm.md, "Web page and metrics"):
// on an opt-in HTTP address, a self-refreshing page (/), the status as JSON
// (/api/status, /api/status?batch=ID: the data of `dofarm status --json`)
// and Prometheus text-format metrics (/metrics). HTTP is cpp-httplib
// (Debian's libcpp-httplib-dev).
//
// Threads. The coordinator's loop, its scheduler and its SQLite store are
// single-threaded, and no HTTP thread ever touches them. The loop calls
// HttpStatus::tick() once per round; when somebody has asked recently and
// the last snapshot is old enough, tick() builds a snapshot (the status JSON
// text, per asked batch too, and the metrics text) and swaps it into a
// mutex-protected holder. HTTP threads only copy a pointer to the latest
// snapshot out of it. A request that finds the snapshot stale (nobody asked
// for a while) waits a bounded time for the loop to publish a fresh one.
//
// Bounds: a fixed pool of HTTP threads with a bounded queue of accepted
// connections (when it is full, the accepting thread serves the connection
// itself, so accepting slows down instead of memory growing); read and
// write timeouts; request line and header lines as cpp-httplib limits them;
// no request body (more than kMaxBodyBytes is 413); GET and HEAD only. The
// loop spends at most about 1/kCostShare of its time building snapshots.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "coordinator/metrics.h"

namespace dofarm::coordinator {

class Scheduler;

struct HttpOptions {
  // HOST:PORT ("127.0.0.1:8080", "[::1]:8080", "0.0.0.0:8080"); port 0: one
  // the OS picks (url() says which). Empty: no HTTP.
  std::string address;
  // The access token, first line of this file. Required when HOST is not a
  // loopback address; when given, every request needs it.
  std::optional<std::filesystem::path> token_file;
  int threads = 4;                    // HTTP threads
  int queue = 16;                     // accepted connections waiting for a thread
  double io_timeout_seconds = 2;      // each read and write of a connection
  double min_interval_seconds = 0.5;  // between two snapshots
};

// HOST:PORT of --http, checked (bad input names the option).
struct HttpAddress {
  std::string host;  // without IPv6 brackets
  int port = 0;
  bool loopback = false;  // 127.0.0.0/8, ::1 or "localhost"
};
HttpAddress parse_http_address(const std::string& text);

// The token from the first line of `file`: a regular file of at most 4 KiB,
// not readable by group or others, 16..256 printable characters without
// spaces. Anything else is bad input naming the file.
std::string load_http_token(const std::filesystem::path& file);

// The address and the token rule of `options` (a non-loopback address
// needs a token file), checked without binding: bad input (SpecError).
// Returns the token (empty when none is asked).
std::string check_http_options(const HttpOptions& options);

// `given` equals `expected`, in time that depends on neither (both are
// hashed with BLAKE2b first, then compared with sodium_memcmp).
bool token_matches(std::string_view given, std::string_view expected);

// The page (one self-contained HTML document: its script and style inline,
// nothing loaded from elsewhere).
const std::string& status_page_html();
// Its Content-Security-Policy: only its own inline script and style (by
// their SHA-256), requests to its own origin only.
const std::string& status_page_csp();

class HttpStatus {
 public:
  // Binds and starts serving (a RuntimeError naming the address when it
  // cannot bind; bad input for a bad address or token file).
  explicit HttpStatus(const HttpOptions& options);
  ~HttpStatus();  // stops and joins the HTTP threads
  HttpStatus(const HttpStatus&) = delete;
  HttpStatus& operator=(const HttpStatus&) = delete;

  // http://HOST:PORT/ with the bound port.
  std::string url() const;
  // On the coordinator's loop only: builds and publishes a snapshot when one
  // is due. Never throws (a failure is logged; the old snapshot stays).
  void tick(Scheduler& scheduler, const ServerCounters& counters);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dofarm::coordinator
