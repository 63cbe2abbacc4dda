"""XLA flag handling and command-line validation."""

import pytest

from match_jax._xla import CPU_FLAG_VALUE, flag_supported, host_device_count, merged_xla_flags


def test_xla_flags_are_merged_not_overridden():
    assert merged_xla_flags(None) == CPU_FLAG_VALUE
    assert merged_xla_flags("--xla_dump_to=/tmp/x") == f"--xla_dump_to=/tmp/x {CPU_FLAG_VALUE}"
    mine = "--xla_cpu_use_fusion_emitters=true --foo=1"
    assert merged_xla_flags(mine) == mine  # the user's own value wins


def test_host_device_count_leaves_a_user_choice_alone():
    assert host_device_count({}, 2) == 2
    assert host_device_count({"XLA_FLAGS": "--xla_dump_to=/tmp/x"}, 16) == 16
    assert host_device_count({"JAX_NUM_CPU_DEVICES": "1"}, 16) is None
    assert host_device_count({"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}, 16) is None
    assert host_device_count({}, 0) == 1


def test_flag_only_for_jaxlib_that_knows_it():
    # jaxlib 0.11.2's XLA aborts on the flag ("Unknown flag in XLA_FLAGS"); 0.9-0.10 need it for speed
    assert flag_supported("0.10.2") and flag_supported("0.9.2") and flag_supported("0.4.38")
    assert not flag_supported("0.11.2") and not flag_supported("0.12.0") and not flag_supported("1.0")
    assert flag_supported(None)


def test_package_import_sets_the_flag_where_supported():
    import os
    from importlib import metadata

    import match_jax  # noqa: F401

    present = "--xla_cpu_use_fusion_emitters" in os.environ.get("XLA_FLAGS", "")
    assert present == flag_supported(metadata.version("jaxlib"))


@pytest.mark.parametrize("argv, message", [
    (["--baseline", "spiral", "--episodes", "0"], "--episodes must be >= 1, got 0"),
    (["--baseline", "spiral", "--noise-mm", "-1"], "--noise-mm must be a finite number >= 0, got -1.0"),
    (["--baseline", "spiral", "--break-force", "-5"], "--break-force must be > 0 N, got -5.0"),
    (["--baseline", "vices"], "invalid choice: 'vices'"),
])
def test_eval_cli_rejects_bad_input(argv, message, capsys):
    import eval as eval_cli

    with pytest.raises(SystemExit):
        eval_cli.parse_args(argv)
    assert message in capsys.readouterr().err


def test_compilation_cache_directory_choice(tmp_path):
    from match_jax import compile_cache

    assert compile_cache.cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "match_jax" / "jax"
    assert compile_cache.cache_dir({"JAX_COMPILATION_CACHE_DIR": "/x/y"}) == compile_cache.pathlib.Path("/x/y")
    for off in ("0", "false", "off"):
        assert compile_cache.cache_dir({"MATCH_JAX_COMPILATION_CACHE": off}) is None
        assert compile_cache.enable({"MATCH_JAX_COMPILATION_CACHE": off}) is None
