#include "trainer/config.h"

#include <gtest/gtest.h>

#include "common/error.h"

namespace dofarm::trainer {
namespace {

TEST(TrainConfig, DefaultsAreThesisValues) {
  TrainConfig c = load_train_config("");
  EXPECT_TRUE(c.model.has_coc());
  EXPECT_EQ(c.model.effective_channels(), (std::vector<int>{36, 48, 64, 85, 113}));
  c.model.inputs.pop_back();  // coc
  EXPECT_FALSE(c.model.has_coc());
  EXPECT_EQ(c.model.effective_channels(), (std::vector<int>{32, 43, 57, 76, 101}));
  EXPECT_EQ(c.data.sequence, 7);
  EXPECT_EQ(c.data.crop, 64);
  EXPECT_FLOAT_EQ(c.data.stop_probability, 0.25f);
  EXPECT_FLOAT_EQ(c.loss.l1, 0.8f);
  EXPECT_FLOAT_EQ(c.loss.log, 0.2f);
  EXPECT_EQ(c.train.batch, 4);
  EXPECT_FLOAT_EQ(c.train.beta2, 0.99f);
}

TEST(TrainConfig, ReadsFileAndOverrides) {
  TrainConfig c = parse_train_config(
      "[train]\nepochs = 5\nlr = 2e-4\n[model]\nchannels = [8, 8, 8, 8, 8]\n", "t.toml",
      {"train.epochs=2", "train.device=cpu", "data.albedo=\"version\""});
  EXPECT_EQ(c.train.epochs, 2);
  EXPECT_FLOAT_EQ(c.train.lr, 2e-4f);
  EXPECT_EQ(c.train.device, "cpu");
  EXPECT_EQ(c.data.albedo, AlbedoSource::kVersion);
  EXPECT_EQ(c.model.effective_channels(), (std::vector<int>{8, 8, 8, 8, 8}));
}

TEST(TrainConfig, UnknownKeyIsALocatedError) {
  try {
    parse_train_config("[train]\nepochs = 5\n  epoch = 3\n", "t.toml");
    FAIL() << "no error";
  } catch (const SpecError& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.rfind("t.toml:3:11: \"train.epoch\": unknown key; [train] takes ", 0), 0u)
        << what;
    EXPECT_NE(what.find("train.epochs"), std::string::npos) << what;
    EXPECT_NE(what.find("train.steps_per_epoch"), std::string::npos) << what;
  }
}

TEST(TrainConfig, BadValueIsALocatedError) {
  try {
    parse_train_config("[train]\nepochs = -1\n", "t.toml");
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.loc().line, 2);
    EXPECT_EQ(e.loc().column, 10);
    EXPECT_EQ(e.key(), "train.epochs");
    EXPECT_NE(std::string(e.what()).find("got -1"), std::string::npos) << e.what();
  }
  EXPECT_THROW(parse_train_config("", "t.toml", {"train.epochs=zero"}), SpecError);
  EXPECT_THROW(parse_train_config("", "t.toml", {"train.nothing=1"}), SpecError);
  EXPECT_THROW(parse_train_config("", "t.toml", {"data.crop=48"}), SpecError);
  EXPECT_THROW(parse_train_config("[train\n", "t.toml"), SpecError);
}

TEST(TrainConfig, PrecisionIsFp32OrBf16) {
  EXPECT_EQ(TrainConfig{}.train.precision, Precision::kFp32);
  TrainConfig c = parse_train_config("[train]\nprecision = \"bf16\"\n", "t.toml");
  EXPECT_EQ(c.train.precision, Precision::kBf16);
  EXPECT_EQ(parse_train_config(to_toml(c), "again.toml").train.precision, Precision::kBf16);
  EXPECT_EQ(incompatible_reason(TrainConfig{}, c), "");  // a resumed run may change it
  try {
    parse_train_config("[train]\nprecision = \"fp16\"\n", "t.toml");
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "train.precision");
    EXPECT_EQ(e.loc().line, 2);
    EXPECT_NE(std::string(e.what()).find("fp32 | bf16"), std::string::npos) << e.what();
  }
}

// Errors from --set name the dotted key, as errors from the file do.
TEST(TrainConfig, OverrideErrorsNameTheDottedKey) {
  try {
    parse_train_config("", "t.toml", {"train.lr=abc"});
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "train.lr") << e.what();
  }
  try {
    parse_train_config("", "t.toml", {"data.crop=48"});
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "data.crop") << e.what();
  }
}

// Floats are written as the user gave them, not widened to double digits.
TEST(TrainConfig, FloatsAreWrittenAsGiven) {
  TrainConfig c = parse_train_config("", "t.toml", {"loss.l1=0.8", "train.lr=3e-4"});
  const std::string text = to_toml(c);
  EXPECT_NE(text.find("l1 = 0.8\n"), std::string::npos) << text;
  EXPECT_EQ(text.find("0.800000"), std::string::npos) << text;
  EXPECT_EQ(parse_train_config(text, "c.toml").loss.l1, 0.8f);
}

// A resumed run starts from its stored config: only the named keys change.
TEST(TrainConfig, OverridesApplyOverABaseConfig) {
  TrainConfig saved = parse_train_config("", "t.toml", {"train.epochs=3", "train.warmup_steps=2"});
  TrainConfig now = load_train_config("", {"train.epochs=5"}, &saved);
  EXPECT_EQ(now.train.epochs, 5);
  EXPECT_EQ(now.train.warmup_steps, 2);  // kept, not the default 500
  EXPECT_EQ(config_changes(saved, now), (std::vector<std::string>{"train.epochs: 3 -> 5"}));
  EXPECT_TRUE(config_changes(saved, saved).empty());
}

TEST(TrainConfig, RoundTripsThroughToml) {
  TrainConfig c = parse_train_config(
      "", "t.toml",
      {"train.epochs=7", "model.recurrent=true", "loss.temporal=0.25", "train.seed=42"});
  TrainConfig back = parse_train_config(to_toml(c), "config.toml");
  EXPECT_EQ(to_toml(back), to_toml(c));
  EXPECT_EQ(back.train.epochs, 7);
  EXPECT_TRUE(back.model.recurrent);
  EXPECT_EQ(back.train.seed, 42u);
}

TEST(TrainConfig, IncompatibleReasonNamesModelKeysOnly) {
  TrainConfig a = load_train_config("");
  TrainConfig b = a;
  b.train.epochs = 500;  // schedule: fine to change on resume
  EXPECT_EQ(incompatible_reason(a, b), "");
  b.model.recurrent = true;
  std::string why = incompatible_reason(a, b);
  EXPECT_NE(why.find("model.recurrent"), std::string::npos) << why;
}

// The no-CoC ablation is a config value: 11 input channels (thesis 4.3.2's
// albedo, normal, roughness and depth beside the radiance), the thesis's
// narrower widths, and the coc buffer no longer needed.
TEST(TrainConfig, NoCocInputListGivesElevenChannels) {
  TrainConfig c = parse_train_config(
      "[model]\ninputs = [\"radiance\", \"albedo\", \"normal\", \"depth\", \"roughness\"]\n",
      "t.toml");
  EXPECT_EQ(c.model.input_channels(), 11);
  EXPECT_FALSE(c.model.has_coc());
  EXPECT_EQ(c.model.effective_channels(), (std::vector<int>{32, 43, 57, 76, 101}));
  // Normalised to name:encoding, so the short and long forms are one config.
  EXPECT_EQ(c.model.inputs[0], "radiance:log1p");
  EXPECT_EQ(c.model.inputs[3], "depth:focal");
  // The same by the old key over the defaults.
  TrainConfig d = parse_train_config("", "t.toml", {"model.dof=false"});
  EXPECT_EQ(d.model.inputs, c.model.inputs);
  // And back: true adds the default coc input, and keeps one already there.
  EXPECT_EQ(parse_train_config("", "t.toml", {"model.dof=true"}, &d).model.inputs,
            TrainConfig{}.model.inputs);
  const TrainConfig thesis = apply_preset("thesis");
  EXPECT_EQ(parse_train_config("", "t.toml", {"model.dof=true"}, &thesis).model.inputs,
            thesis.model.inputs);
}

TEST(TrainConfig, UnknownInputIsAnErrorNamingTheKey) {
  try {
    parse_train_config("[model]\ninputs = [\"radiance\", \"albedo\", \"motion\"]\n", "t.toml");
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "model.inputs");
    EXPECT_EQ(e.loc().line, 2);
    const std::string what = e.what();
    EXPECT_NE(what.find("unknown input 'motion'"), std::string::npos) << what;
    EXPECT_NE(what.find("radiance, albedo, normal, depth, roughness, coc"), std::string::npos)
        << what;
  }
  try {
    parse_train_config("", "t.toml", {"model.inputs=[\"radiance\", \"coc:cubic\"]"});
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.key(), "model.inputs");
    EXPECT_NE(std::string(e.what()).find("unknown encoding 'cubic' of input 'coc'; it takes log, "
                                         "thesis"),
              std::string::npos)
        << e.what();
  }
  // What is denoised must be there, once; an input is listed at most once.
  EXPECT_THROW(parse_train_config("[model]\ninputs = [\"albedo\"]\n", "t.toml"), SpecError);
  EXPECT_THROW(
      parse_train_config("[model]\ninputs = [\"radiance\", \"coc\", \"coc:thesis\"]\n", "t.toml"),
      SpecError);
}

// A run folder's config.toml from before model.inputs (written with
// `dof = ...`, every other key of that time) still loads, as the same inputs.
TEST(TrainConfig, OldDofConfigsStillLoad) {
  const std::string old_model =
      "[model]\nbottleneck = 0\nchannels = []\ndof = {}\nleaky_slope = 0.1\nrecurrent = false\n"
      "[data]\ncoc_log_scale = 3.4965\ncrop = 64\n[train]\nepochs = 3\n";
  auto with = [&](const char* v) {
    std::string t = old_model;
    t.replace(t.find("{}"), 2, v);
    return t;
  };
  TrainConfig on = parse_train_config(with("true"), "config.toml");
  EXPECT_EQ(on.model.inputs, TrainConfig{}.model.inputs);
  EXPECT_EQ(on.model.input_channels(), 12);
  TrainConfig off = parse_train_config(with("false"), "config.toml");
  EXPECT_EQ(off.model.input_channels(), 11);
  EXPECT_FALSE(off.model.has_coc());
  // What it is written back as names the inputs, not dof, and reads back the same.
  const std::string text = to_toml(off);
  EXPECT_EQ(text.find("\ndof"), std::string::npos) << text;
  EXPECT_EQ(parse_train_config(text, "config.toml").model.inputs, off.model.inputs);
  EXPECT_TRUE(incompatible_reason(off, parse_train_config(text, "c.toml")).empty());
  // The coc input on and off are different models.
  EXPECT_NE(incompatible_reason(on, off).find("model.inputs"), std::string::npos);
  // Both forms in one file: which one is meant is unclear.
  EXPECT_THROW(parse_train_config("[model]\ndof = true\ninputs = [\"radiance\"]\n", "t.toml"),
               SpecError);
  EXPECT_THROW(parse_train_config("[model]\ndof = 1\n", "t.toml"), SpecError);
}

TEST(TrainConfig, ThesisPresetHasTheThesisValues) {
  TrainConfig t = apply_preset("thesis");
  EXPECT_EQ(t.model.bottleneck_convs, 3);
  EXPECT_EQ(t.model.decoder, DecoderForm::kThesis);
  EXPECT_EQ(t.loss.log_form, GradientLoss::kThesis);
  EXPECT_FLOAT_EQ(t.loss.l1, 0.8f);
  EXPECT_FLOAT_EQ(t.loss.log, 0.2f);
  EXPECT_EQ(t.train.schedule, Schedule::kThesis);
  EXPECT_EQ(t.train.steps_per_epoch, 0);
  EXPECT_EQ(t.train.best_by, BestBy::kTraining);
  EXPECT_EQ(t.train.grad_clip, 0.0f);
  EXPECT_EQ(TrainConfig{}.train.grad_clip, 1.0f);  // the project's default clips
  EXPECT_EQ(t.train.ema, 0.0f);
  EXPECT_EQ(TrainConfig{}.train.ema, 0.999f);  // and averages the weights
  EXPECT_EQ(t.model.inputs,
            (std::vector<std::string>{"radiance:linear", "albedo:as_stored", "normal:remap01",
                                      "depth:scene", "roughness:as_stored", "coc:thesis"}));
  // Round trip through config.toml, and over a base like any config file.
  EXPECT_TRUE(config_changes(t, parse_train_config(to_toml(t), "c.toml")).empty());
  TrainConfig base;
  base.train.epochs = 7;
  EXPECT_EQ(apply_preset("thesis", base).train.epochs, 7);
  EXPECT_TRUE(config_changes(apply_preset("default", t), TrainConfig{}).empty());
  try {
    apply_preset("thesys");
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_NE(std::string(e.what()).find("unknown preset 'thesys'; presets are default, thesis"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace dofarm::trainer
