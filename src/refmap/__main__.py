from refmap.cli import app

app()
