from stillcap.cli import main

main()
