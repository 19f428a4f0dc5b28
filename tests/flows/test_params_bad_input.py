"""Bad parameters a flow's model refuses in one line (exit 2 from the CLI) before the flow writes
anything, rather than a traceback from the task that trips over them."""

import pytest
from typer.testing import CliRunner

from flows.cli import app
from flows.corpus import corpus
from flows.params import ParamsError
from flows.params_data import CorpusParams

runner = CliRunner()


@pytest.mark.parametrize("width, height, option, value", [(33, 35, "width", 33), (34, 35, "height", 35)])
def test_an_odd_corpus_size_is_refused_in_one_line_naming_the_option(width, height, option, value, data_root):
    # Was ValueError "corpus size 33x35: width and height must be even" from generate_corpus, a traceback.
    args = ["corpus", "--minutes", "0.05", "--seed", "2", "--width", str(width), "--height", str(height)]
    result = runner.invoke(app, args, terminal_width=400)
    said = f"--{option}: {value} is odd; the corpus videos (H.264, 4:2:0) need an even width and height"
    assert result.exit_code == 2 and result.output.strip() == said, result.output
    assert not any(data_root.iterdir())  # refused before the run made anything
    with pytest.raises(ParamsError, match=rf"^{option}: {value} is odd;"):  # a deployment: the flow's first line
        corpus.fn(minutes=0.05, seed=2, width=width, height=height)
    assert not any(data_root.iterdir())


def test_even_corpus_sizes_pass():
    assert (CorpusParams.of({"width": 34, "height": 32}).width, CorpusParams().height) == (34, 360)
