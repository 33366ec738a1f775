from forest.cli import main

main()
