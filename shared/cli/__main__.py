from shared.cli.entry import main

main()
