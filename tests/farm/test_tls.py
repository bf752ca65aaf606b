"""A running Dask scheduler over TLS: the --tls-* files reach distributed's Security; without them, exit 2."""

import shutil
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("bpy")

from nephele.farm import cli  # noqa: E402
from nephele.farm.frames import check_image  # noqa: E402

SCENE = Path(__file__).with_name("cube_scene.py")


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    """A throw-away CA and one certificate for 127.0.0.1 (scheduler, workers and client), made by openssl."""
    if not shutil.which("openssl"):
        pytest.skip("openssl not found")
    d = tmp_path_factory.mktemp("tls")

    def run(*args):
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "2",
        "-subj", "/CN=nephele-test-ca")
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "node.key", "-out", "node.csr", "-subj", "/CN=localhost")
    (d / "ext.cnf").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\nbasicConstraints=CA:FALSE\n"
                               "authorityKeyIdentifier=keyid,issuer\nkeyUsage=digitalSignature,keyEncipherment\n"
                               "extendedKeyUsage=serverAuth,clientAuth\n")
    run("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-out", "node.pem",
        "-days", "2", "-extfile", "ext.cnf")
    return d


def test_render_through_tls_scheduler(certs, tmp_path, capsys):
    from distributed import LocalCluster
    from distributed.security import Security

    ca, pem, key = (str(certs / n) for n in ("ca.pem", "node.pem", "node.key"))
    sec = Security(tls_ca_file=ca, tls_scheduler_cert=pem, tls_scheduler_key=key, tls_worker_cert=pem,
                   tls_worker_key=key, tls_client_cert=pem, tls_client_key=key, require_encryption=True)
    with LocalCluster(n_workers=1, threads_per_worker=1, security=sec, protocol="tls://", host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster:
        addr = cluster.scheduler_address
        assert addr.startswith("tls://")
        rc = cli.main(["render", str(SCENE), "--frames", "1-2", "--out", str(tmp_path / "o"), "--scheduler", addr])
        err = capsys.readouterr().err
        assert rc == 2 and "cannot connect to the Dask scheduler" in err and "--tls-ca-file" in err
        rc = cli.main(["render", str(SCENE), "--frames", "1-2", "--out", str(tmp_path / "o"), "--scheduler", addr,
                       "--tls-ca-file", ca, "--tls-cert", pem, "--tls-key", key])
        err = capsys.readouterr().err
    assert rc == 0, err
    assert "2/2 done" in err and "ETA" in err  # the plain-text progress line (stderr is not a terminal)
    for f in (1, 2):
        assert check_image(tmp_path / "o" / f"frame_{f:04d}.png") == (32, 24)
