"""A data root a writing command cannot use is named in one line, exit 5, before any work:
a file where one of its folders belongs, a warehouse file that is a folder, not DuckDB, or not
Worldline's (these were found only when the work reached them: after the videos were encoded,
or once Prefect had started, with a traceback)."""

import duckdb
import pytest
from typer.testing import CliRunner

from flows.cli import app
from schemas.errors import EXIT_ENVIRONMENT, EnvironmentFault
from warehouse import preflight
from warehouse.store import Warehouse, WarehouseUnusable

from tests.support import good_videos

runner = CliRunner()


def test_a_file_where_a_folder_belongs_is_named(tmp_path):
    preflight.check_folders(tmp_path)  # nothing there yet: fine
    (tmp_path / "clips").mkdir()
    (tmp_path / "shards").write_text("mine\n")
    with pytest.raises(EnvironmentFault, match=r"/shards: a file where the data root keeps its shards/ folder; "
                                               r"move it aside$") as caught:
        preflight.check_folders(tmp_path)
    assert caught.value.exit_code == EXIT_ENVIRONMENT and (tmp_path / "shards").read_text() == "mine\n"


def test_a_warehouse_file_that_is_not_one_is_refused(tmp_path):
    path = tmp_path / "lineage.duckdb"
    preflight.check_warehouse(path)  # none yet: the writer makes it
    path.mkdir()
    with pytest.raises(WarehouseUnusable, match="cannot open the warehouse: it is a folder$"):
        preflight.check_warehouse(path)
    path.rmdir()
    path.write_text("hello\n")
    with pytest.raises(EnvironmentFault, match="the warehouse is damaged"):
        preflight.check_warehouse(path)
    path.unlink()
    with duckdb.connect(str(path)) as con:
        con.execute("CREATE TABLE someone_elses (x INT)")
    with pytest.raises(WarehouseUnusable, match=r"not a Worldline warehouse \(tables \['someone_elses'\]"):
        preflight.check_warehouse(path)
    assert WarehouseUnusable("x").exit_code == EXIT_ENVIRONMENT


def test_a_worldline_warehouse_passes_even_while_this_process_writes_it(tmp_path):
    path = tmp_path / "lineage.duckdb"
    with Warehouse(path):
        preflight.check_warehouse(path)  # a second, read-only open here would conflict: not made
    preflight.check_warehouse(path)


@pytest.mark.parametrize("damage", ["shards_file", "warehouse_folder", "warehouse_text"])
def test_curate_on_an_unusable_data_root_is_one_line_exit_5(tmp_path, data_root, damage):
    inbox = tmp_path / "inbox"
    good_videos(inbox, seeds=(0,))
    if damage == "shards_file":
        (data_root / "shards").write_text("mine\n")
    elif damage == "warehouse_folder":
        (data_root / "lineage.duckdb").mkdir()
    else:
        (data_root / "lineage.duckdb").write_text("hello\n")
    result = runner.invoke(app, ["curate", str(inbox)])
    said = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == EXIT_ENVIRONMENT and len(said) == 1, result.output
    assert said[0].startswith(str(data_root / ("shards" if damage == "shards_file" else "lineage.duckdb")))
    assert not (data_root / "clips").exists() and not (data_root / "analysis").exists()  # nothing ran
