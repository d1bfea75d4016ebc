"""The on-disk compilation cache: bounded, locked, and shared safely by processes.

Each check runs in fresh processes (the cache is process-wide JAX configuration), with the
cache and export folders in a temporary folder.
"""

import os
import subprocess
import sys
import textwrap

_PROGRAM = textwrap.dedent("""
    import sys
    import jax, jax.numpy as jnp
    import axialmix  # float64
    from fitting.solve import COMPILATION_CACHE_BYTES, enable_compilation_cache
    folder = enable_compilation_cache(sys.argv[1])
    assert jax.config.jax_compilation_cache_max_size == COMPILATION_CACHE_BYTES
    total = 0.0
    for k in range(int(sys.argv[2])):
        f = jax.jit(lambda x, k=k: jnp.sum(jnp.cumsum(jnp.sin(x * (k + 1)))))
        total += float(f(jnp.linspace(0.0, 1.0, 64 + k)))
    print(repr(total))
""")


def _run(folder, count, env):
    return subprocess.Popen([sys.executable, "-c", _PROGRAM, str(folder), str(count)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def test_processes_sharing_the_cache_agree_and_the_cache_is_locked(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "home"),
           "AXIALMIX_COMPILATION_CACHE": "on"}
    folder = tmp_path / "jax"
    # Two processes compile and write the same entries at the same time, then a third reads
    # them all back: every process gives the same sums as a cache-free computation would.
    first = [_run(folder, 12, env) for _ in range(2)]
    outputs = [process.communicate(timeout=300) for process in first]
    for process, (_, err) in zip(first, outputs, strict=True):
        assert process.returncode == 0, err
    third = _run(folder, 12, env)
    out, err = third.communicate(timeout=300)
    assert third.returncode == 0, err
    assert "Error reading persistent compilation cache" not in err
    assert {outputs[0][0], outputs[1][0], out} == {out}
    entries = [p for p in folder.iterdir() if p.name.endswith("-cache")]
    assert len(entries) >= 12
    assert (folder / ".lockfile").exists()  # the bounded cache takes its file lock


def test_a_cache_written_without_a_bound_is_taken_over(tmp_path):
    # An older cache folder: entries without access-time files (JAX's unbounded cache).
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "home"),
           "AXIALMIX_COMPILATION_CACHE": "on"}
    folder = tmp_path / "jax"
    old = subprocess.run([sys.executable, "-c", textwrap.dedent(f"""
        import jax, jax.numpy as jnp
        jax.config.update("jax_compilation_cache_dir", {str(folder)!r})
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        print(float(jax.jit(lambda x: jnp.sum(jnp.exp(x)))(jnp.ones(5))))
    """)], capture_output=True, text=True, env=env, timeout=300)
    assert old.returncode == 0, old.stderr
    assert not list(folder.glob("*-atime"))
    new = _run(folder, 3, env)
    _, err = new.communicate(timeout=300)
    assert new.returncode == 0, err
    assert "Error writing persistent compilation cache" not in err, err
    entries = list(folder.glob("*-cache"))
    assert len(entries) >= 4 and all(e.with_name(e.name[:-5] + "atime").exists()
                                     for e in entries)


def test_the_cache_can_be_turned_off(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "home"),
           "AXIALMIX_COMPILATION_CACHE": "off"}
    program = _PROGRAM.replace(
        "assert jax.config.jax_compilation_cache_max_size == COMPILATION_CACHE_BYTES", "")
    done = subprocess.run([sys.executable, "-c", program, str(tmp_path / "jax"), "2"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    assert not (tmp_path / "jax").exists() and not (tmp_path / "home").exists()
