// `dofarm verify DIR`: checks an output folder against its job store (or its
// manifest), one line per shard; exit 0 when everything holds, 1 otherwise,
// 2 when DIR is not a folder. The work is coordinator/verify.h.
#include <filesystem>
#include <iostream>
#include <memory>

#include "apps/commands.h"
#include "common/error.h"
#include "coordinator/verify.h"

namespace dofarm {

namespace fs = std::filesystem;

Command add_verify(CLI::App& app) {
  struct Args {
    std::string dir, state, batch;
    bool json = false;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "verify",
      "Check an output folder: every shard its job store (or manifest) lists is there, whole "
      "and listed; shards no record lists; staged tiles");
  cmd->add_option("dir", a->dir, "output folder")->type_name("DIR")->required();
  cmd->add_option("--state", a->state,
                  "job store folder of a standalone coordinator (default DIR/.dofarm-state, "
                  "else manifest.json alone)")
      ->type_name("DIR");
  cmd->add_option("--batch", a->batch,
                  "the batch to check against (default: the one that writes DIR)");
  cmd->add_flag("--json", a->json, "print JSON");
  return {cmd, [a]() {
            std::error_code ec;
            if (!fs::is_directory(a->dir, ec))
              throw SpecError(FileLoc{}, "", a->dir + ": not a folder");
            coordinator::VerifyOptions o;
            o.state_dir = a->state;
            o.batch_id = a->batch;
            const coordinator::FolderReport r = coordinator::verify_folder(a->dir, o);
            if (a->json)
              std::cout << coordinator::folder_report_json(r).dump(2) << std::endl;
            else
              coordinator::print_folder_report(r, std::cout);
            return r.ok() ? kExitOk : kExitRuntime;
          }};
}

}  // namespace dofarm
