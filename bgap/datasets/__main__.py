from bgap.runner.numerics import command

main = command("bgap.commands.datasets")
if __name__ == "__main__":
    main()
